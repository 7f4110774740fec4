// The page's history of telemetry: a fixed-size ring of buckets (time, and min/max of every
// series), filled by the WebSocket whether the plots are paused or not, and read by the plots
// for whatever time range they show. Fixed-size typed arrays: appending never allocates.
import { N_SERIES, type TelemetryFrame } from "./protocol";

export class TelemetryStore {
  readonly capacity: number;
  private readonly mask: number;
  private readonly t: Float64Array;
  /** [physical index][series][min,max] */
  private readonly mm: Float32Array;
  private start = 0;
  private len = 0;
  /** Buckets ever appended (for the test hook and the "data moves" check). */
  appended = 0;
  /** Times the history restarted because the device time went backwards (a new loop run). */
  restarts = 0;

  constructor(capacityPow2 = 1 << 18) {
    if ((capacityPow2 & (capacityPow2 - 1)) !== 0) throw new Error("capacity must be a power of two");
    this.capacity = capacityPow2;
    this.mask = capacityPow2 - 1;
    this.t = new Float64Array(capacityPow2);
    this.mm = new Float32Array(capacityPow2 * N_SERIES * 2);
  }

  get length(): number {
    return this.len;
  }

  clear(): void {
    this.start = 0;
    this.len = 0;
  }

  firstTime(): number {
    return this.len ? this.t[this.start] : NaN;
  }

  lastTime(): number {
    return this.len ? this.t[(this.start + this.len - 1) & this.mask] : NaN;
  }

  append(f: TelemetryFrame): void {
    const stride = N_SERIES * 2;
    for (let b = 0; b < f.nBuckets; b++) {
      const tb = f.t[b];
      if (!Number.isFinite(tb)) continue;
      if (this.len && tb < this.lastTime()) {
        // A new run attached (its clock starts again): drop the old run's history rather
        // than draw one line across both.
        this.clear();
        this.restarts++;
      }
      let p: number;
      if (this.len < this.capacity) {
        p = (this.start + this.len) & this.mask;
        this.len++;
      } else {
        p = this.start;
        this.start = (this.start + 1) & this.mask;
      }
      this.t[p] = tb;
      this.mm.set(f.minMax.subarray(b * stride, (b + 1) * stride), p * stride);
      this.appended++;
    }
  }

  timeAt(i: number): number {
    return this.t[(this.start + i) & this.mask];
  }

  min(i: number, s: number): number {
    return this.mm[((this.start + i) & this.mask) * N_SERIES * 2 + s * 2];
  }

  max(i: number, s: number): number {
    return this.mm[((this.start + i) & this.mask) * N_SERIES * 2 + s * 2 + 1];
  }

  /** First logical index whose time is >= t (len when none). */
  lowerBound(t: number): number {
    let lo = 0;
    let hi = this.len;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (this.timeAt(mid) < t) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }

  /** True when series s has at least one finite value in logical range [i0, i1). */
  hasFinite(s: number, i0: number, i1: number): boolean {
    // Sampled check from the newest end: NaN series (F_pred without a model, F_true on a real
    // board) are NaN everywhere, so a few probes decide it cheaply.
    const step = Math.max(1, Math.floor((i1 - i0) / 64));
    for (let i = i1 - 1; i >= i0; i -= step) if (Number.isFinite(this.max(i, s))) return true;
    return false;
  }
}

/** What a time plot draws: x and, per series, min and max (null = gap). */
export interface Columns {
  t: number[];
  min: (number | null)[][];
  max: (number | null)[][];
  /** Store buckets behind these columns (1 per column when not aggregated). */
  bucketsInRange: number;
}

/**
 * Reads [t0, t1] for drawing at a given width: when the range holds more buckets than about two
 * per pixel column, the buckets are merged into `columns` columns (min of mins, max of maxes),
 * so drawing cost follows the plot's width, not the window's length, and a spike in any bucket
 * still reaches the screen. Values are multiplied by `scale[s]` (unit conversion).
 */
export function readColumns(store: TelemetryStore, t0: number, t1: number, columns: number, scale: number[]): Columns {
  const i0 = store.lowerBound(t0);
  const i1 = store.lowerBound(t1 + 1e-12 + (t1 - t0) * 1e-9);
  const n = i1 - i0;
  const out: Columns = { t: [], min: [], max: [], bucketsInRange: n };
  for (let s = 0; s < N_SERIES; s++) {
    out.min.push([]);
    out.max.push([]);
  }
  if (n <= 0) return out;
  const fin = (v: number): number | null => (Number.isFinite(v) ? v : null);
  if (n <= columns * 2) {
    for (let i = i0; i < i1; i++) {
      out.t.push(store.timeAt(i));
      for (let s = 0; s < N_SERIES; s++) {
        out.min[s].push(fin(store.min(i, s) * scale[s]));
        out.max[s].push(fin(store.max(i, s) * scale[s]));
      }
    }
    return out;
  }
  const span = t1 - t0;
  const lo = new Float64Array(N_SERIES);
  const hi = new Float64Array(N_SERIES);
  let i = i0;
  let prevEmpty = false;
  for (let c = 0; c < columns && i < i1; c++) {
    const cEnd = t0 + (span * (c + 1)) / columns;
    const cStartT = store.timeAt(i);
    lo.fill(Infinity);
    hi.fill(-Infinity);
    let any = false;
    while (i < i1 && (store.timeAt(i) < cEnd || c === columns - 1)) {
      for (let s = 0; s < N_SERIES; s++) {
        const a = store.min(i, s);
        const b = store.max(i, s);
        if (a < lo[s]) lo[s] = a;
        if (b > hi[s]) hi[s] = b;
      }
      any = true;
      i++;
    }
    if (!any) {
      // No data in this column (the loop was gone): one null breaks the line there.
      if (!prevEmpty && out.t.length) {
        out.t.push(t0 + (span * c) / columns);
        for (let s = 0; s < N_SERIES; s++) {
          out.min[s].push(null);
          out.max[s].push(null);
        }
      }
      prevEmpty = true;
      continue;
    }
    prevEmpty = false;
    out.t.push(cStartT);
    for (let s = 0; s < N_SERIES; s++) {
      out.min[s].push(Number.isFinite(lo[s]) ? lo[s] * scale[s] : null);
      out.max[s].push(Number.isFinite(hi[s]) ? hi[s] * scale[s] : null);
    }
  }
  return out;
}

/** Rows of the store in [t0, t1] as CSV, at the store's full resolution (not the screen's). */
export function toCsv(store: TelemetryStore, t0: number, t1: number, names: readonly string[]): string {
  const i0 = store.lowerBound(t0);
  const i1 = store.lowerBound(t1 + 1e-12);
  const head = ["t_s"];
  for (const n of names) head.push(`${n}_min`, `${n}_max`);
  const lines = [head.join(",")];
  const num = (v: number): string => (Number.isFinite(v) ? String(v) : "");
  for (let i = i0; i < i1; i++) {
    const row = [store.timeAt(i).toFixed(6)];
    for (let s = 0; s < names.length; s++) row.push(num(store.min(i, s)), num(store.max(i, s)));
    lines.push(row.join(","));
  }
  return lines.join("\n") + "\n";
}
