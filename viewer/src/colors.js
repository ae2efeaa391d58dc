// Colour helpers shared by the 3D view and the colour bar (same rules as
// litege_core/render/colormap.py).
import { VIRIDIS } from './viridis.js';

/** A round spacing (1, 2, 2.5 or 5 × 10^k) giving about ``target`` intervals over ``span``. */
export function niceStep(span, target = 10) {
  if (!(span > 0) || !Number.isFinite(span)) return 0;
  const raw = span / target;
  const power = 10 ** Math.floor(Math.log10(raw));
  for (const factor of [1, 2, 2.5, 5, 10]) {
    if (raw <= factor * power * (1 + 1e-9)) return factor * power;
  }
  return 10 * power;
}

/** Round tick values within [vmin, vmax]. */
export function niceTicks(vmin, vmax, target = 5) {
  const step = niceStep(vmax - vmin, target);
  if (!step) return [vmin];
  const ticks = [];
  for (let t = Math.ceil(vmin / step - 1e-9) * step; t <= vmax + step * 1e-6; t += step) {
    ticks.push(Math.abs(t) < step * 1e-9 ? 0 : t);
  }
  return ticks;
}

/** viridis(t) for t in [0, 1] as [r, g, b] in [0, 1] (linear interpolation of the table). */
export function viridis(t) {
  const x = Math.min(Math.max(Number.isFinite(t) ? t : 0, 0), 1) * 255;
  const i = Math.min(Math.floor(x), 254);
  const f = x - i;
  const a = VIRIDIS[i];
  const b = VIRIDIS[i + 1];
  return [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f];
}

/** RGBA bytes of the 256-entry table (a 256 × 1 texture). */
export function viridisBytes() {
  const data = new Uint8Array(256 * 4);
  VIRIDIS.forEach((c, i) => {
    data[i * 4] = Math.round(c[0] * 255);
    data[i * 4 + 1] = Math.round(c[1] * 255);
    data[i * 4 + 2] = Math.round(c[2] * 255);
    data[i * 4 + 3] = 255;
  });
  return data;
}

/** Smooth colouring of a point set: coordinates normalized over the bounding box → RGB. */
export function coordinateColors(positions, low = 0.12, high = 0.95) {
  const n = positions.length / 3;
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < n; i++) {
    for (let k = 0; k < 3; k++) {
      const v = positions[i * 3 + k];
      if (v < lo[k]) lo[k] = v;
      if (v > hi[k]) hi[k] = v;
    }
  }
  const out = new Float32Array(n * 3);
  for (let i = 0; i < n; i++) {
    for (let k = 0; k < 3; k++) {
      const span = hi[k] - lo[k] > 0 ? hi[k] - lo[k] : 1;
      out[i * 3 + k] = low + (high - low) * (positions[i * 3 + k] - lo[k]) / span;
    }
  }
  return out;
}

/** Format a number for labels: 4 significant digits, no trailing zeros. */
export function fmt(value) {
  if (!Number.isFinite(value)) return String(value);
  return Number(value.toPrecision(4)).toString();
}
