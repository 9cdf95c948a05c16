// A running plot of the order parameter phi in [0, 1] against the step, drawn at the
// canvas's size on screen with ticks large enough to read across a room.
const INK = "#1d2330", MUTED = "#4e5768", GRID = "#dfe3ea", LINE = "#2f6fde";

export class OrderPlot {
  constructor(canvas, capacity = 600) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.capacity = capacity;
    this.steps = [];
    this.values = [];
    this.tickPx = 0;    // CSS pixels of the tick labels (tests read it)
    this.x0 = 0;        // CSS pixels from the left edge to the phi axis (tests read it)
  }

  clear() { this.steps = []; this.values = []; this.draw(); }

  push(step, phi) {
    this.steps.push(step);
    this.values.push(phi);
    if (this.values.length > this.capacity) { this.steps.shift(); this.values.shift(); }
  }

  // the backing store follows the size on screen, so text is drawn at its real size: the
  // ticks at the page's font size (call when the layout changes, not every frame)
  resize() {
    const c = this.canvas;
    this.dpr = window.devicePixelRatio || 1;
    this.tickPx = parseFloat(getComputedStyle(document.documentElement).fontSize) || 16;
    const w = Math.round(c.clientWidth * this.dpr), h = Math.round(c.clientHeight * this.dpr);
    if (w > 0 && h > 0 && (c.width !== w || c.height !== h)) { c.width = w; c.height = h; }
    this.draw();
  }

  draw() {
    const { ctx, canvas, dpr } = this;
    if (!dpr) return;
    const w = canvas.width, h = canvas.height;
    const font = this.tickPx * dpr;
    ctx.font = `${font}px system-ui, sans-serif`;
    // the phi axis' label, upright (one letter), then the ticks' labels, 0.6 font sizes apart
    const ticks = ["0", "0.5", "1"];
    const labelWidth = ctx.measureText("φ").width, tickWidth = Math.max(...ticks.map((t) => ctx.measureText(t).width));
    const pad = 0.35 * font, gap = 0.6 * font;
    const left = 0.3 * font + labelWidth + gap + tickWidth + pad, right = 0.8 * font, top = 0.7 * font,
      bottom = 2.5 * font;
    const x0 = left, x1 = w - right, y0 = h - bottom, y1 = top;
    const y = (v) => y0 + v * (y1 - y0);
    ctx.clearRect(0, 0, w, h);
    ctx.lineWidth = Math.max(1, dpr);
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    ticks.forEach((text, i) => {
      const v = i / 2;
      ctx.strokeStyle = v === 0 ? MUTED : GRID;
      ctx.beginPath(); ctx.moveTo(x0, y(v)); ctx.lineTo(x1, y(v)); ctx.stroke();
      ctx.fillStyle = INK;
      ctx.fillText(text, x0 - pad, y(v));
    });
    ctx.textAlign = "left";
    ctx.fillText("φ", 0.3 * font, y(0.75));  // between two ticks, not beside one
    this.x0 = x0 / dpr;
    // step axis: nice round steps over what the plot holds
    const first = this.steps.length ? this.steps[0] : 0;
    const last = Math.max(first + 10, this.steps.length ? this.steps[this.steps.length - 1] : 10);
    const x = (s) => x0 + ((s - first) / (last - first)) * (x1 - x0);
    const every = niceStep((last - first) / Math.max(2, Math.floor((x1 - x0) / (6 * font))));
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    for (let s = Math.ceil(first / every) * every; s <= last; s += every) {
      ctx.strokeStyle = MUTED;
      ctx.beginPath(); ctx.moveTo(x(s), y0); ctx.lineTo(x(s), y0 + 0.3 * font); ctx.stroke();
      ctx.fillStyle = INK;
      ctx.fillText(String(s), x(s), y0 + 0.4 * font);
    }
    ctx.fillStyle = MUTED;
    ctx.textAlign = "right";
    ctx.fillText("step", x1, y0 + 1.4 * font);
    // the curve
    if (this.values.length < 2) return;
    ctx.strokeStyle = LINE;
    ctx.lineWidth = 2.5 * dpr;
    ctx.lineJoin = "round";
    ctx.beginPath();
    this.values.forEach((v, i) => {
      const px = x(this.steps[i]), py = y(Math.min(1, Math.max(0, v)));
      if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
    });
    ctx.stroke();
  }
}

// 1, 2 or 5 times a power of ten, at least `raw`
function niceStep(raw) {
  const p = 10 ** Math.floor(Math.log10(Math.max(raw, 1)));
  for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
  return 10 * p;
}
