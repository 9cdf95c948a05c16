// Decode a binary frame from the server (layout: flocking/play/session.py).
const HEADER = 36;

export function decodeFrame(buffer) {
  const view = new DataView(buffer);
  const magic = String.fromCharCode(...new Uint8Array(buffer, 0, 4));
  if (magic !== "FLK1") throw new Error("not a flocking play frame");
  const dim = view.getUint8(4);
  const flags = view.getUint8(5);
  const n = view.getUint32(8, true);
  const step = view.getFloat64(12, true);
  const phi = view.getFloat32(20, true);
  const box = [view.getFloat32(24, true), view.getFloat32(28, true), view.getFloat32(32, true)];
  const positions = new Uint16Array(buffer, HEADER, n * dim);        // x / L * 65536
  const headings = new Uint8Array(buffer, HEADER + 2 * n * dim, n * (dim - 1));
  return { dim, n, step, phi, box, running: (flags & 1) === 1, positions, headings };
}
