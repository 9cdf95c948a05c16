// A running plot of the order parameter phi in [0, 1].
export class OrderPlot {
  constructor(canvas, capacity = 600) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.capacity = capacity;
    this.values = [];
  }

  clear() { this.values = []; this.draw(); }

  push(phi) {
    this.values.push(phi);
    if (this.values.length > this.capacity) this.values.shift();
  }

  draw() {
    const { ctx, canvas } = this;
    const w = canvas.width, h = canvas.height, top = 24, bottom = 8, left = 34, right = 8;
    const y = (v) => top + (1 - v) * (h - top - bottom);
    ctx.clearRect(0, 0, w, h);
    ctx.font = "12px system-ui, sans-serif";
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    for (const v of [0, 0.5, 1]) {
      ctx.strokeStyle = v === 0.5 ? "#e3e6ec" : "#c9ced8";
      ctx.beginPath();
      ctx.moveTo(left, y(v));
      ctx.lineTo(w - right, y(v));
      ctx.stroke();
      ctx.fillStyle = "#5b6475";
      ctx.fillText(v.toFixed(1), left - 6, y(v));
    }
    const values = this.values;
    if (values.length < 2) return;
    const dx = (w - left - right) / (this.capacity - 1);
    ctx.strokeStyle = "#2f6fde";
    ctx.lineWidth = 2;
    ctx.beginPath();
    values.forEach((v, i) => {
      const px = left + i * dx, py = y(Math.min(1, Math.max(0, v)));
      if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
    });
    ctx.stroke();
    ctx.lineWidth = 1;
  }
}
