// Draw frames: 2D as short strokes along each heading, 3D in a rotatable perspective view.
// Colour is the heading's angle (its azimuth in 3D); strokes of one colour share one path.

export const BACKGROUND = "#0f1420";
const HUES = 36;           // colour buckets
const LAYERS = 3;          // depth layers in 3D, far ones dimmer

// Particles are written straight into an ImageData (one 32-bit word per pixel): ten
// thousand short segments cost about a millisecond, far less than as canvas strokes.
const palette = Array.from({ length: HUES }, (_, i) => hslToRgb(i / HUES, 0.85, 0.6));
const css = palette.map(([r, g, b]) => `rgb(${r},${g},${b})`);
const rgba = ([r, g, b], k = 1) => ((255 << 24) | (Math.round(b * k) << 16) | (Math.round(g * k) << 8) | Math.round(r * k)) >>> 0;
const BG = rgba([15, 20, 32]);
// colour[layer * HUES + hue], heads and (dimmer) tails; layer 0 is the nearest
const heads = Array.from({ length: LAYERS * HUES }, (_, k) => rgba(palette[k % HUES], 1 - 0.3 * Math.floor(k / HUES)));
const tails = Array.from({ length: LAYERS * HUES }, (_, k) => rgba(palette[k % HUES], 0.55 * (1 - 0.3 * Math.floor(k / HUES))));

// two species: Okabe and Ito's orange and sky blue (told apart with every common colour
// blindness), by depth layer like the hues
const SPECIES = [[230, 159, 0], [86, 180, 233]];
export const SPECIES_CSS = SPECIES.map(([r, g, b]) => `rgb(${r},${g},${b})`);
const speciesHeads = Array.from({ length: LAYERS * 2 }, (_, k) => rgba(SPECIES[k % 2], 1 - 0.3 * Math.floor(k / 2)));
const speciesTails = Array.from({ length: LAYERS * 2 }, (_, k) => rgba(SPECIES[k % 2], 0.55 * (1 - 0.3 * Math.floor(k / 2))));
const WALL = "rgba(236, 240, 248, 0.95)";
const OBSTACLE = "rgba(92, 102, 124, 0.92)";
const OBSTACLE_EDGE = "rgba(222, 228, 240, 0.95)";

function hslToRgb(h, s, l) {
  const f = (k) => {
    const t = (k + h * 12) % 12;
    return Math.round(255 * (l - s * Math.min(l, 1 - l) * Math.max(-1, Math.min(t - 3, 9 - t, 1))));
  };
  return [f(0), f(8), f(4)];
}

export class Renderer {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.yaw = 0.6;
    this.pitch = 0.45;
    this.image = null;
    this.order = null;
    // walls per axis, obstacles and their periodic images ({centre, radius}) and species counts, from the server's state
    this.scene = { walls: [], obstacles: [], counts: null };
  }

  // colour tables: by species when there are two and they add up to the frame's N, else by heading
  colours(n) {
    const counts = this.scene.counts;
    if (counts && counts.length === 2 && counts[0] + counts[1] === n) {
      return { kinds: 2, heads: speciesHeads, tails: speciesTails, first: counts[0] };
    }
    return { kinds: HUES, heads, tails, first: -1 };
  }

  // 2D: where the box is on the canvas, in canvas pixels
  layout2d(frame) {
    const { canvas } = this;
    const [lx, ly] = frame.box;
    const scale = Math.min(canvas.width / lx, canvas.height / ly);
    return { lx, ly, scale, x0: (canvas.width - lx * scale) / 2, y0: (canvas.height + ly * scale) / 2 };
  }

  // the box coordinates [x, y] under a mouse event's client point in 2D, or null outside the box
  toBox(frame, clientX, clientY) {
    const rect = this.canvas.getBoundingClientRect();
    const px = ((clientX - rect.left) * this.canvas.width) / rect.width;
    const py = ((clientY - rect.top) * this.canvas.height) / rect.height;
    const { lx, ly, scale, x0, y0 } = this.layout2d(frame);
    const x = (px - x0) / scale, y = (y0 - py) / scale;
    return x >= 0 && x <= lx && y >= 0 && y <= ly ? [x, y] : null;
  }

  draw(frame) {
    const { ctx, canvas } = this;
    if (!this.image || this.image.width !== canvas.width || this.image.height !== canvas.height) {
      this.image = ctx.createImageData(canvas.width, canvas.height);
      this.pixels = new Uint32Array(this.image.data.buffer);
    }
    this.pixels.fill(BG);
    if (frame.dim === 2) this.draw2d(frame); else this.draw3d(frame);
  }

  // a segment from (x0, y0) (tail colour) to (x1, y1) (head colour), 1 or 2 pixels thick
  segment(x0, y0, x1, y1, tail, head, thick) {
    const { pixels } = this, w = this.image.width, h = this.image.height;
    const dx = x1 - x0, dy = y1 - y0;
    const steps = Math.max(1, Math.ceil(Math.max(Math.abs(dx), Math.abs(dy))));
    for (let s = 0; s <= steps; s++) {
      const x = Math.floor(x0 + (dx * s) / steps), y = Math.floor(y0 + (dy * s) / steps);
      const c = 2 * s < steps ? tail : head;
      if (x < 0 || y < 0 || x >= w - 1 || y >= h - 1) continue;
      const o = y * w + x;
      pixels[o] = c;
      if (thick) { pixels[o + 1] = c; pixels[o + w] = c; pixels[o + w + 1] = c; }
    }
  }

  // this.order: particle indices sorted by bucket (a stable counting sort)
  buckets(bucketOf, n, count) {
    const start = new Uint32Array(count + 1);
    if (!this.order || this.order.length < n) this.order = new Uint32Array(n);
    const key = new Uint16Array(n);
    for (let i = 0; i < n; i++) { key[i] = bucketOf(i); start[key[i] + 1]++; }
    for (let b = 0; b < count; b++) start[b + 1] += start[b];
    const fill = start.slice(0, count);
    for (let i = 0; i < n; i++) this.order[fill[key[i]]++] = i;
  }

  draw2d(frame) {
    const { n, positions: p, headings: h } = frame;
    const { lx, ly, scale, x0, y0 } = this.layout2d(frame);
    const sx = (lx * scale) / 65536, sy = (ly * scale) / 65536;
    const dpr = window.devicePixelRatio || 1;
    const len = Math.max(2, Math.min(10 * dpr, 0.7 * scale));
    const thick = len >= 4 * dpr && n <= 100000;
    const cos = new Float32Array(256), sin = new Float32Array(256);
    for (let a = 0; a < 256; a++) { cos[a] = len * Math.cos(a * Math.PI / 128); sin[a] = len * Math.sin(a * Math.PI / 128); }
    const pal = this.colours(n);
    for (let i = 0; i < n; i++) {
      const x = x0 + (p[2 * i] + 0.5) * sx, y = y0 - (p[2 * i + 1] + 0.5) * sy;
      const c = pal.first < 0 ? (h[i] * HUES) >> 8 : Number(i >= pal.first);
      this.segment(x - cos[h[i]], y + sin[h[i]], x, y, pal.tails[c], pal.heads[c], thick);
    }
    this.ctx.putImageData(this.image, 0, 0);
    this.scenery2d(frame);
  }

  // obstacles as discs (each image the server's Space sends, across periodic sides too), walls as bright lines
  scenery2d(frame) {
    const { ctx } = this;
    const { lx, ly, scale, x0, y0 } = this.layout2d(frame);
    const { walls, obstacles } = this.scene;
    const dpr = window.devicePixelRatio || 1;
    ctx.save();
    ctx.beginPath();
    ctx.rect(x0, y0 - ly * scale, lx * scale, ly * scale);
    ctx.clip();
    ctx.fillStyle = OBSTACLE;
    ctx.strokeStyle = OBSTACLE_EDGE;
    ctx.lineWidth = 1.5 * dpr;
    for (const { centre, radius } of obstacles) {
      ctx.beginPath();
      ctx.arc(x0 + centre[0] * scale, y0 - centre[1] * scale, radius * scale, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
    }
    ctx.restore();
    ctx.strokeStyle = WALL;
    ctx.lineWidth = Math.max(4 * dpr, 0.012 * this.canvas.width);
    ctx.lineCap = "square";
    const w = ctx.lineWidth / 2;  // inside the canvas, over the box's edge
    ctx.beginPath();
    if (walls[0]) {
      for (const x of [x0 + w, x0 + lx * scale - w]) { ctx.moveTo(x, y0); ctx.lineTo(x, y0 - ly * scale); }
    }
    if (walls[1]) {
      for (const y of [y0 - w, y0 - ly * scale + w]) { ctx.moveTo(x0, y); ctx.lineTo(x0 + lx * scale, y); }
    }
    ctx.stroke();
  }

  // 3D: the box centred at the origin, turned by yaw (about the vertical z axis) then pitch
  projector(frame) {
    const { canvas } = this;
    const [lx, ly, lz] = frame.box;
    const radius = Math.hypot(lx, ly, lz) / 2;
    const distance = 2.8 * radius;
    const focal = 0.5 * Math.min(canvas.width, canvas.height) * Math.sqrt(distance ** 2 - radius ** 2) / radius;
    const cy = Math.cos(this.yaw), syw = Math.sin(this.yaw), cp = Math.cos(this.pitch), sp = Math.sin(this.pitch);
    const w2 = canvas.width / 2, h2 = canvas.height / 2;
    return (x, y, z, out) => {
      x -= lx / 2; y -= ly / 2; z -= lz / 2;
      const x1 = cy * x - syw * y, y1 = syw * x + cy * y;
      const depth = cp * y1 - sp * z, up = sp * y1 + cp * z;
      const d = distance + depth;
      out[0] = w2 + (focal * x1) / d;
      out[1] = h2 - (focal * up) / d;
      out[2] = (depth + radius) / (2 * radius); // 0 near .. 1 far
      out[3] = focal / d;                       // pixels per unit length at that depth
      return out;
    };
  }

  draw3d(frame) {
    const { ctx } = this;
    const { n, positions: p, headings: h } = frame;
    const [lx, ly, lz] = frame.box;
    const project = this.projector(frame);
    const a = [0, 0, 0, 0], b = [0, 0, 0, 0];
    const len = 0.035 * Math.max(lx, ly, lz);
    const cx = lx / 65536, cy = ly / 65536, cz = lz / 65536;
    const seg = new Float32Array(4 * n);
    const colour = new Uint16Array(n);
    const pal = this.colours(n), K = pal.kinds;
    for (let i = 0; i < n; i++) {
      const x = (p[3 * i] + 0.5) * cx, y = (p[3 * i + 1] + 0.5) * cy, z = (p[3 * i + 2] + 0.5) * cz;
      const az = h[2 * i] * Math.PI / 128, uz = h[2 * i + 1] / 127.5 - 1, rho = Math.sqrt(Math.max(0, 1 - uz * uz));
      project(x, y, z, a);
      project(x - len * rho * Math.cos(az), y - len * rho * Math.sin(az), z - len * uz, b);
      seg[4 * i] = b[0]; seg[4 * i + 1] = b[1]; seg[4 * i + 2] = a[0]; seg[4 * i + 3] = a[1];
      const kind = pal.first < 0 ? (h[2 * i] * HUES) >> 8 : Number(i >= pal.first);
      colour[i] = Math.min(LAYERS - 1, Math.floor(a[2] * LAYERS)) * K + kind;
    }
    // far layers first, so that near particles cover them
    this.buckets((i) => LAYERS * K - 1 - colour[i], n, LAYERS * K);
    const thick = n <= 100000;
    for (let s = 0; s < n; s++) {
      const i = this.order[s], c = colour[i];
      this.segment(seg[4 * i], seg[4 * i + 1], seg[4 * i + 2], seg[4 * i + 3], pal.tails[c], pal.heads[c], thick && c < K * (LAYERS - 1));
    }
    ctx.putImageData(this.image, 0, 0);
    // obstacles: the outline of each sphere as seen (a circle of the projected radius)
    ctx.strokeStyle = OBSTACLE_EDGE;
    ctx.fillStyle = "rgba(92, 102, 124, 0.35)";
    ctx.lineWidth = 1.5 * (window.devicePixelRatio || 1);
    for (const { centre, radius } of this.scene.obstacles) {
      if (centre.length !== 3) continue;
      project(centre[0], centre[1], centre[2], a);
      ctx.beginPath();
      ctx.arc(a[0], a[1], radius * a[3], 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
    }
    // the box's edges; those of a wall's faces bright and thick
    const walls = this.scene.walls;
    const sides = [lx, ly, lz];
    for (const bright of [false, true]) {
      ctx.strokeStyle = bright ? WALL : "rgba(200, 210, 230, 0.35)";
      ctx.lineWidth = bright ? 2.5 * (window.devicePixelRatio || 1) : 1;
      ctx.beginPath();
      for (let axis = 0; axis < 3; axis++) {   // the 12 edges: 4 along each axis
        if (Boolean(walls[(axis + 1) % 3] || walls[(axis + 2) % 3]) !== bright) continue;
        for (let corner = 0; corner < 4; corner++) {
          const from = [0, 0, 0];
          from[(axis + 1) % 3] = (corner & 1) * sides[(axis + 1) % 3];
          from[(axis + 2) % 3] = (corner >> 1) * sides[(axis + 2) % 3];
          const to = from.slice();
          to[axis] = sides[axis];
          project(from[0], from[1], from[2], a);
          project(to[0], to[1], to[2], b);
          ctx.moveTo(a[0], a[1]);
          ctx.lineTo(b[0], b[1]);
        }
      }
      ctx.stroke();
    }
  }

  // turn the 3D view by dragging
  attachDrag(canvas, redraw) {
    let last = null;
    canvas.addEventListener("pointerdown", (e) => { last = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener("pointerup", () => { last = null; });
    canvas.addEventListener("pointermove", (e) => {
      if (!last) return;
      this.yaw += (e.clientX - last[0]) * 0.01;
      this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch + (e.clientY - last[1]) * 0.01));
      last = [e.clientX, e.clientY];
      redraw();
    });
  }
}

// A colour wheel: which colour flies which way (seen from above in 3D).
export function drawCompass(canvas) {
  const ctx = canvas.getContext("2d");
  const c = canvas.width / 2, r = 0.93 * c;
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "rgba(15, 20, 32, 0.75)";
  ctx.beginPath(); ctx.arc(c, c, c, 0, 2 * Math.PI); ctx.fill();
  ctx.lineWidth = Math.max(2, canvas.width / 34);
  ctx.lineCap = "round";
  for (let b = 0; b < HUES; b++) {
    const angle = (b + 0.5) * 2 * Math.PI / HUES;
    ctx.strokeStyle = css[b];
    ctx.beginPath();
    ctx.moveTo(c + 0.35 * r * Math.cos(angle), c - 0.35 * r * Math.sin(angle));
    ctx.lineTo(c + r * Math.cos(angle), c - r * Math.sin(angle));
    ctx.stroke();
  }
}
