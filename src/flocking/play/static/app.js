// flocking play: the page. Controls send JSON messages; the server streams binary frames.
import { decodeFrame } from "./frame.js";
import { OrderPlot } from "./plot.js";
import { Renderer, drawCompass } from "./render.js";

const $ = (id) => document.getElementById(id);
const flockCanvas = $("flock");
const renderer = new Renderer(flockCanvas);
const plot = new OrderPlot($("plot"));
const NOISE_MAX = { angular: 2 * Math.PI, vectorial: 2 };
const NOISE_SCALE = { angular: ["0: none", "π", "2π: random"], vectorial: ["0: none", "1", "2"] };

// what tests and curious users can read in the console
const stats = { frames: 0, fps: 0, drawMs: 0, step: 0, phi: 0, n: 0, dim: 2, running: true, errors: [], model: null,
                refused: null, busy: false, plot };
window.flockPlay = stats;

let socket = null;
let latest = null;       // the newest frame, drawn at the next animation frame
let drawn = null;        // the frame on screen (redrawn when the 3D view turns)
let lastStep = -1;
let model = null;        // the model the server runs (from its "state" replies)
let refused = null;      // why the server refused this tab, if it did
let busy = false;        // the server said that a change takes a while; its next frame ends that

// -- the socket ----------------------------------------------------------------------------

function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  socket = new WebSocket(`${scheme}://${location.host}/ws`);
  socket.binaryType = "arraybuffer";
  socket.onmessage = (event) => {
    if (typeof event.data === "string") onReply(JSON.parse(event.data));
    else onFrame(decodeFrame(event.data));
  };
  socket.onclose = () => {
    if (refused) {
      offline(`The server refused this tab: ${refused}. The server is still running: reload this page ` +
              "once that is done.");
      $("readout").textContent = "refused by the server";
    } else {
      offline("Disconnected from the server. Start `flocking play` again and reload this page.");
      $("readout").textContent = "disconnected";
    }
  };
}

// the controls of a tab without a server do nothing: disable them and say why, for good
function offline(text) {
  document.body.classList.add("offline");
  for (const el of document.querySelectorAll("#controls fieldset")) el.disabled = true;
  clearTimeout(sayTimer);
  $("message").textContent = text;
  $("message").classList.add("error");
}

function send(message) {
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(message));
}

function onFrame(frame) {
  if (busy) { busy = false; stats.busy = false; if (!document.body.classList.contains("offline")) $("message").textContent = ""; }
  if (frame.step < lastStep || (model && (frame.n !== stats.n || frame.dim !== stats.dim))) plot.clear();
  lastStep = frame.step;
  latest = frame;
  stats.frames++;
  Object.assign(stats, { step: frame.step, phi: frame.phi, n: frame.n, dim: frame.dim, running: frame.running });
  plot.push(frame.step, frame.phi);
}

function onReply(reply) {
  if (reply.type === "refused") {
    refused = reply.message;
    stats.refused = refused;
  } else if (reply.type === "error") {
    stats.errors.push(reply.message);
    say(reply.message, true);
  } else if (reply.type === "state") {
    model = reply.model;
    stats.model = model;
    sync(reply);
  } else if (reply.type === "busy") {   // a change that takes a while: said until the next frame
    busy = true;
    stats.busy = true;
    clearTimeout(sayTimer);
    $("message").textContent = reply.message;
    $("message").classList.remove("error");
  } else if (reply.type === "config") {
    download(new Blob([reply.toml], { type: "application/toml" }), reply.filename);
    say(`Saved ${reply.filename}: run it with  flocking run --config ${reply.filename}`);
  }
}

// -- drawing -------------------------------------------------------------------------------

let frameCount = 0, since = performance.now();
function animate(now) {
  if (latest) {
    const t0 = performance.now();
    renderer.draw(latest);
    stats.drawMs = 0.9 * stats.drawMs + 0.1 * (performance.now() - t0);
    drawn = latest;
    latest = null;
    plot.draw();
    frameCount++;
  }
  if (now - since >= 1000) {
    stats.fps = (frameCount * 1000) / (now - since);
    frameCount = 0;
    since = now;
  }
  if (drawn && !document.body.classList.contains("offline")) readout(drawn);  // unchanged text costs no layout
  requestAnimationFrame(animate);
}

function readout(frame) {
  const box = frame.box.slice(0, frame.dim).map((l) => l.toFixed(1)).join(" × ");
  setText($("phi"), frame.phi.toFixed(3));
  setText($("readout"), `step ${frame.step}   ·   N = ${frame.n}   ·   box ${box}   ·   ` +
          `${stats.fps.toFixed(0)} frames/s${frame.running ? "" : "   ·   paused"}`);
}

function setText(el, text) { if (el.textContent !== text) el.textContent = text; }

// -- controls ------------------------------------------------------------------------------

let pending = {};
let timer = null;
function setParams(params) {          // coalesce slider drags: at most one message per 60 ms
  Object.assign(pending, params);
  if (timer === null) timer = setTimeout(() => { send({ type: "set", params: pending }); pending = {}; timer = null; }, 60);
}

function sliderValue(input) {
  return input.step && Number.isInteger(Number(input.step)) ? parseInt(input.value, 10) : parseFloat(input.value);
}

function showValue(input) {
  const out = document.querySelector(`output[for="${input.id}"]`);
  if (out) out.textContent = Number.isInteger(Number(input.step)) ? input.value : Number(input.value).toFixed(2);
  if (out && input.id === "vision") out.textContent += "°";
}

for (const input of document.querySelectorAll("input[data-param]")) {
  input.addEventListener("input", () => { showValue(input); setParams({ [input.id]: sliderValue(input) }); });
}

$("density").addEventListener("input", () => showValue($("density")));
$("density").addEventListener("change", () => setParams({ density: parseFloat($("density").value) }));
$("n").addEventListener("change", () => {
  const n = Number($("n").value);
  if (Number.isInteger(n) && n >= 1) setParams({ n }); else say("N must be a whole number of at least 1", true);
});
$("seed").addEventListener("change", () => setParams({ seed: Number($("seed").value) }));
$("steps_per_frame").addEventListener("input", () => {
  showValue($("steps_per_frame"));
  send({ type: "steps_per_frame", value: parseInt($("steps_per_frame").value, 10) });
});

for (const radio of document.querySelectorAll('input[type="radio"]')) {
  radio.addEventListener("change", () => {
    if (!radio.checked) return;
    if (radio.name === "dim") setParams({ dim: Number(radio.value) });
    else if (radio.name === "coupling") setParams(speciesParams());
    else if (radio.name === "noise_type") {
      const noise = Math.min(parseFloat($("noise").value), NOISE_MAX[radio.value]);
      $("b-noise").value = Math.min(parseFloat($("b-noise").value), NOISE_MAX[radio.value]);
      setParams({ noise_type: radio.value, noise, ...speciesParams() });
    } else setParams({ [radio.name]: radio.value });
  });
}

// -- the extensions: walls, obstacles, a second species, vision, chirality and cohesion -----

// walls: one switch per axis (z only in 3D); the server takes "periodic,wall,..."
function boundaryParam() {
  const axes = model && model.dim === 3 ? ["x", "y", "z"] : ["x", "y"];
  return axes.map((a) => ($(`wall-${a}`).checked ? "wall" : "periodic")).join(",");
}
for (const a of ["x", "y", "z"]) $(`wall-${a}`).addEventListener("change", () => setParams({ boundary: boundaryParam() }));

// species B with its own fraction, speed and noise; the coupling sign J_AB = J_BA = +1 or -1
function speciesParams() {
  if (!$("species-on").checked) return { species: [], coupling: null };
  const f = parseFloat($("b-fraction").value);
  const sign = Number(document.querySelector('input[name="coupling"]:checked').value);
  return {
    species: [{ name: "A", fraction: Math.round((1 - f) * 100) / 100 },
              { name: "B", fraction: f, speed: parseFloat($("b-speed").value), noise: parseFloat($("b-noise").value) }],
    coupling: [[1, sign], [sign, 1]],
  };
}
$("species-on").addEventListener("change", () => setParams(speciesParams()));
for (const input of document.querySelectorAll("input[data-species]")) {
  input.addEventListener("input", () => { showValue(input); if ($("species-on").checked) setParams(speciesParams()); });
}

// the vision slider is in degrees, the model's half-angle in radians
$("vision").addEventListener("input", () => {
  showValue($("vision"));
  const degrees = parseInt($("vision").value, 10);
  setParams({ vision: degrees >= 180 ? Math.PI : (degrees * Math.PI) / 180 });
});

// obstacles: a click on the 2D flock drops one there, or removes the one clicked
$("obstacle-radius").addEventListener("input", () => showValue($("obstacle-radius")));
flockCanvas.addEventListener("click", (e) => {
  if (!drawn || drawn.dim !== 2 || document.body.classList.contains("offline")) return;
  const at = renderer.toBox(drawn, e.clientX, e.clientY);
  if (at) send({ type: "obstacle", at, radius: parseFloat($("obstacle-radius").value) });
});
$("clear-obstacles").addEventListener("click", () => setParams({ obstacles: [] }));

$("play").addEventListener("click", () => send({ type: stats.running ? "pause" : "play" }));
$("step").addEventListener("click", () => send({ type: "step" }));
$("reset").addEventListener("click", () => { send({ type: "reset", init: $("init").value }); plot.clear(); });
$("init").addEventListener("change", () => { send({ type: "reset", init: $("init").value }); plot.clear(); });
$("export").addEventListener("click", () => send({ type: "config" }));
$("snapshot").addEventListener("click", () => {
  flockCanvas.toBlob((blob) => download(blob, `flocking-step-${stats.step}.png`), "image/png");
});

// show what the server really runs (it may have refused or adjusted a value)
function sync(reply) {
  const m = reply.model;
  const active = document.activeElement;
  const set = (id, value) => { const el = $(id); if (el !== active || !el.matches(":active")) { el.value = value; showValue(el); } };
  $("noise").max = NOISE_MAX[m.noise_type];
  for (const id of ["noise", "radius", "k", "speed", "alignment", "delay"]) set(id, m[id]);
  set("density", Math.round(m.density * 10) / 10);
  if ($("n") !== active) $("n").value = m.n;
  if ($("seed") !== active) $("seed").value = m.seed;
  $("n").max = reply.limits.n;
  set("steps_per_frame", reply.steps_per_frame);
  $("init").value = reply.init;
  for (const name of ["noise_type", "neighbours", "dim"]) {
    const radio = document.querySelector(`input[name="${name}"][value="${m[name]}"]`);
    if (radio) radio.checked = true;
  }
  syncExtensions(reply);
  for (const el of document.querySelectorAll(".metric")) el.classList.toggle("hidden", m.neighbours !== "metric");
  for (const el of document.querySelectorAll(".topological")) el.classList.toggle("hidden", m.neighbours !== "topological");
  for (const el of document.querySelectorAll(".voronoi")) el.classList.toggle("hidden", m.neighbours !== "voronoi");
  $("play").textContent = reply.running ? "Pause" : "Play";
  stats.running = reply.running;
  const three = m.dim === 3;
  flockCanvas.parentElement.classList.toggle("three", three);
  $("hint").hidden = !three;
  $("wheel-caption").textContent = three ? "colour = heading, seen from above" : "colour = heading";
  $("noise-scale").replaceChildren(...NOISE_SCALE[m.noise_type].map((t) => Object.assign(document.createElement("span"), { textContent: t })));
  // R and v0 against the box: what a class can picture
  const side = Math.min(...m.box);
  $("radius-hint").textContent = `how far a particle sees: the box is ${fewDigits(side / m.radius)} R wide`;
  $("speed-hint").textContent = `distance moved per step: crossing the box takes ${fewDigits(side / (m.speed * m.dt))} steps`;
}

// the extension controls and the drawing's walls, obstacles and species colours
function syncExtensions(reply) {
  const m = reply.model, active = document.activeElement;
  const set = (id, value) => { const el = $(id); if (el !== active || !el.matches(":active")) { el.value = value; showValue(el); } };
  const three = m.dim === 3;
  let walls = (m.boundary || "periodic").split(",");
  if (walls.length === 1) walls = Array(m.dim).fill(walls[0]);
  walls = walls.map((w) => w === "wall");
  ["x", "y", "z"].forEach((a, i) => { $(`wall-${a}`).checked = Boolean(walls[i]); });
  const obstacles = m.obstacles || [];
  const species = m.species || [];
  const two = species.length === 2;
  $("species-on").checked = two;
  if (two) {
    const b = species[1];
    set("b-fraction", b.fraction ?? reply.species_counts[1] / m.n);
    set("b-speed", b.speed ?? m.speed);
    set("b-noise", b.noise ?? m.noise);
    const sign = m.coupling && m.coupling[0][1] < 0 ? "-1" : "1";
    document.querySelector(`input[name="coupling"][value="${sign}"]`).checked = true;
  }
  $("b-noise").max = NOISE_MAX[m.noise_type];
  for (const el of document.querySelectorAll("#second input[data-species], #second input[name='coupling']")) el.disabled = !two;
  const vision = m.vision ?? Math.PI;
  set("vision", Math.round((vision * 180) / Math.PI));
  set("chirality", m.chirality ?? 0);
  set("cohesion", m.cohesion ?? 0);
  for (const el of document.querySelectorAll(".two-d")) el.classList.toggle("hidden", three);
  for (const el of document.querySelectorAll(".three-d")) el.classList.toggle("hidden", !three);
  // what each folded section holds, readable while it is closed
  const named = ["x", "y", "z"].filter((a, i) => walls[i]);
  const space = [named.length ? `walls ${named.join(", ")}` : "",
                 obstacles.length ? `${obstacles.length} obstacle${obstacles.length > 1 ? "s" : ""}` : ""];
  $("space-state").textContent = space.filter(Boolean).join(" · ") || "none";
  $("second-state").textContent = two ? `${reply.species_counts[1]} of ${m.n}` : "off";
  const sight = [vision < Math.PI ? `${Math.round((vision * 180) / Math.PI)}°` : "", m.chirality ? `ω ${m.chirality}` : "",
                 m.cohesion ? `β ${m.cohesion}` : ""];
  $("sight-state").textContent = sight.filter(Boolean).join(" · ") || "all round";
  const discs = (reply.obstacle_images || []).map((row) => ({ centre: row.slice(0, -1), radius: row[row.length - 1] }));
  renderer.scene = { walls, obstacles: discs, counts: two ? reply.species_counts : null };
  $("legend").classList.toggle("hidden", !two);
  document.querySelector(".wheel").classList.toggle("hidden", two);
  flockCanvas.classList.toggle("drop", !three);
  if (drawn) latest = latest || drawn;  // redraw with the new walls and obstacles
}

function fewDigits(x) { return x >= 10 ? Math.round(x).toString() : x.toFixed(1); }

let sayTimer = null;
function say(text, error = false) {
  if (document.body.classList.contains("offline")) return;  // the reason it is offline stays
  const el = $("message");
  el.textContent = text;
  el.classList.toggle("error", error);
  clearTimeout(sayTimer);
  sayTimer = setTimeout(() => { el.textContent = ""; }, error ? 8000 : 6000);
}

function download(blob, name) {
  const a = document.createElement("a");
  a.href = URL.createObjectURL(blob);
  a.download = name;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 1000);
}

// canvases are drawn at their size on screen (times the pixel ratio), which the layout sets
function fit() {
  const dpr = window.devicePixelRatio || 1;
  const side = Math.min(2048, Math.round(flockCanvas.clientWidth * dpr));
  if (side > 0 && flockCanvas.width !== side) {
    flockCanvas.width = flockCanvas.height = side;
    if (drawn) latest = latest || drawn;
  }
  const compass = $("compass"), c = Math.round(compass.clientWidth * dpr);
  if (c > 0 && compass.width !== c) { compass.width = compass.height = c; drawCompass(compass); }
  plot.resize();
}
new ResizeObserver(fit).observe(document.body);

renderer.attachDrag(flockCanvas, () => { if (drawn && drawn.dim === 3) latest = latest || drawn; });
fit();
connect();
requestAnimationFrame(animate);
