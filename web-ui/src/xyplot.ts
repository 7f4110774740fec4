// The force-against-depth plot of the last N seconds, drawn on a canvas: each bucket's midpoint
// (depth, force), joined in time order, older parts fainter, so a ramp cycle's loading and
// unloading paths (the hysteresis loop) and its drift from cycle to cycle are visible.

export interface XYTrace {
  label: string;
  color: string;
  x: number[];
  y: number[];
  dash?: number[];
}

function niceStep(span: number, targetTicks: number): number {
  const raw = span / Math.max(1, targetTicks);
  const p = 10 ** Math.floor(Math.log10(raw));
  const m = raw / p;
  return (m < 1.5 ? 1 : m < 3.5 ? 2 : m < 7.5 ? 5 : 10) * p;
}

function ticks(lo: number, hi: number, n: number): number[] {
  const step = niceStep(hi - lo, n);
  const out: number[] = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-6; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
  return out;
}

function fmt(v: number, step: number): string {
  const d = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
  return v.toFixed(Math.min(d, 4));
}

export class XYPlot {
  private readonly ctx: CanvasRenderingContext2D;
  private cssW = 300;
  private cssH = 300;
  traces: XYTrace[] = [];

  constructor(
    readonly canvas: HTMLCanvasElement,
    readonly xLabel: string,
    readonly yLabel: string,
  ) {
    const ctx = canvas.getContext("2d");
    if (!ctx) throw new Error("no 2D canvas context");
    this.ctx = ctx;
  }

  setSize(w: number, h: number): void {
    const dpr = window.devicePixelRatio || 1;
    this.cssW = Math.max(200, Math.floor(w));
    this.cssH = Math.max(160, Math.floor(h));
    this.canvas.style.width = `${this.cssW}px`;
    this.canvas.style.height = `${this.cssH}px`;
    this.canvas.width = Math.round(this.cssW * dpr);
    this.canvas.height = Math.round(this.cssH * dpr);
  }

  draw(traces: XYTrace[]): void {
    this.traces = traces;
    const ctx = this.ctx;
    const dpr = window.devicePixelRatio || 1;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, this.cssW, this.cssH);
    const L = 56;
    const R = 12;
    const T = 10;
    const B = 40;
    const pw = this.cssW - L - R;
    const ph = this.cssH - T - B;

    let x0 = Infinity;
    let x1 = -Infinity;
    let y0 = Infinity;
    let y1 = -Infinity;
    for (const tr of traces) {
      for (let i = 0; i < tr.x.length; i++) {
        const x = tr.x[i];
        const y = tr.y[i];
        if (!Number.isFinite(x) || !Number.isFinite(y)) continue;
        if (x < x0) x0 = x;
        if (x > x1) x1 = x;
        if (y < y0) y0 = y;
        if (y > y1) y1 = y;
      }
    }
    if (!Number.isFinite(x0)) {
      x0 = 0;
      x1 = 1;
      y0 = 0;
      y1 = 1;
    }
    // Include the origin when close: the loop's start at (0, 0) is part of the picture.
    if (x0 > 0 && x0 < (x1 - x0) * 0.5) x0 = 0;
    if (y0 > 0 && y0 < (y1 - y0) * 0.5) y0 = 0;
    const padX = Math.max((x1 - x0) * 0.05, 1e-3);
    const padY = Math.max((y1 - y0) * 0.06, 1e-2);
    x0 -= padX;
    x1 += padX;
    y0 -= padY;
    y1 += padY;
    const sx = (x: number) => L + ((x - x0) / (x1 - x0)) * pw;
    const sy = (y: number) => T + ph - ((y - y0) / (y1 - y0)) * ph;

    // Grid and tick labels.
    ctx.font = "12px system-ui, sans-serif";
    ctx.lineWidth = 1;
    const xt = ticks(x0, x1, Math.max(3, Math.floor(pw / 70)));
    const yt = ticks(y0, y1, Math.max(3, Math.floor(ph / 40)));
    const xs = xt.length > 1 ? xt[1] - xt[0] : 1;
    const ys = yt.length > 1 ? yt[1] - yt[0] : 1;
    ctx.strokeStyle = "#e5e7eb";
    ctx.fillStyle = "#1f2937";
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    for (const v of xt) {
      const px = Math.round(sx(v)) + 0.5;
      ctx.beginPath();
      ctx.moveTo(px, T);
      ctx.lineTo(px, T + ph);
      ctx.stroke();
      ctx.fillText(fmt(v, xs), px, T + ph + 5);
    }
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    for (const v of yt) {
      const py = Math.round(sy(v)) + 0.5;
      ctx.beginPath();
      ctx.moveTo(L, py);
      ctx.lineTo(L + pw, py);
      ctx.stroke();
      ctx.fillText(fmt(v, ys), L - 6, py);
    }
    ctx.strokeStyle = "#9ca3af";
    ctx.strokeRect(L + 0.5, T + 0.5, pw, ph);
    ctx.textAlign = "center";
    ctx.textBaseline = "bottom";
    ctx.fillText(this.xLabel, L + pw / 2, this.cssH - 2);
    ctx.save();
    ctx.translate(14, T + ph / 2);
    ctx.rotate(-Math.PI / 2);
    ctx.textBaseline = "middle";
    ctx.fillText(this.yLabel, 0, 0);
    ctx.restore();

    // Traces: split into chunks, older chunks drawn fainter.
    ctx.save();
    ctx.beginPath();
    ctx.rect(L, T, pw, ph);
    ctx.clip();
    ctx.lineJoin = "round";
    for (const tr of traces) {
      const n = tr.x.length;
      if (n < 2) continue;
      const chunks = Math.min(24, n - 1);
      ctx.strokeStyle = tr.color;
      ctx.lineWidth = 1.6;
      ctx.setLineDash(tr.dash ?? []);
      for (let c = 0; c < chunks; c++) {
        const a = Math.floor((c * (n - 1)) / chunks);
        const b = Math.floor(((c + 1) * (n - 1)) / chunks);
        ctx.globalAlpha = 0.15 + 0.85 * ((c + 1) / chunks);
        ctx.beginPath();
        let pen = false;
        for (let i = a; i <= b; i++) {
          const x = tr.x[i];
          const y = tr.y[i];
          if (!Number.isFinite(x) || !Number.isFinite(y)) {
            pen = false;
            continue;
          }
          if (pen) ctx.lineTo(sx(x), sy(y));
          else ctx.moveTo(sx(x), sy(y));
          pen = true;
        }
        ctx.stroke();
      }
      // The newest point, so the person sees where the probe is now.
      const lx = tr.x[n - 1];
      const ly = tr.y[n - 1];
      if (Number.isFinite(lx) && Number.isFinite(ly)) {
        ctx.globalAlpha = 1;
        ctx.setLineDash([]);
        ctx.fillStyle = tr.color;
        ctx.beginPath();
        ctx.arc(sx(lx), sy(ly), 3.5, 0, Math.PI * 2);
        ctx.fill();
      }
    }
    ctx.restore();
  }
}

/** Signed area enclosed by a path (shoelace), closing it from the last point to the first. */
export function enclosedArea(x: number[], y: number[]): number {
  let a = 0;
  const n = x.length;
  for (let i = 0; i < n; i++) {
    const j = (i + 1) % n;
    a += x[i] * y[j] - x[j] * y[i];
  }
  return a / 2;
}
