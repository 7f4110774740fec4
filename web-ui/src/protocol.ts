// Decoding of what infer-server sends (docs/web-protocol.md): binary telemetry frames of
// min/max buckets and the status object (the gRPC Status message as JSON).

/** The series of a telemetry frame, in the order the server writes them. */
export const SERIES = [
  "F_ref",
  "rtob_force",
  "F_pred",
  "position_x",
  "velocity",
  "acceleration",
  "F_true",
] as const;
export type SeriesName = (typeof SERIES)[number];
export const N_SERIES = SERIES.length;

const MAGIC = 0x31545048; // "HPT1" read as a little-endian u32
const HEADER_BYTES = 16;

/** One decoded frame: bucket start times and, per bucket and series, min then max. */
export interface TelemetryFrame {
  nBuckets: number;
  /** Device time (s) of each bucket's first step. */
  t: Float64Array;
  /** Row-major [bucket][series][min,max] for the first N_SERIES series only. */
  minMax: Float32Array;
}

export class FrameError extends Error {}

/**
 * Decodes one binary frame. Series beyond the 7 the page knows are skipped (the protocol lets
 * the server add more later); a frame that is short, has the wrong magic or version, or has
 * fewer series than the page needs is rejected with a message that says which.
 */
export function decodeFrame(buf: ArrayBuffer): TelemetryFrame {
  if (buf.byteLength < HEADER_BYTES) throw new FrameError(`frame of ${buf.byteLength} bytes is shorter than its header`);
  const view = new DataView(buf);
  const magic = view.getUint32(0, true);
  if (magic !== MAGIC) throw new FrameError(`bad magic 0x${magic.toString(16)} (expected "HPT1")`);
  const version = view.getUint16(4, true);
  if (version !== 1) throw new FrameError(`unsupported frame version ${version}`);
  const nSeries = view.getUint16(6, true);
  const nBuckets = view.getUint32(8, true);
  if (nSeries < N_SERIES) throw new FrameError(`frame has ${nSeries} series, the page needs ${N_SERIES}`);
  const need = HEADER_BYTES + 8 * nBuckets + 8 * nBuckets * nSeries;
  if (buf.byteLength !== need) throw new FrameError(`frame of ${buf.byteLength} bytes, header says ${need}`);
  const t = new Float64Array(nBuckets);
  for (let b = 0; b < nBuckets; b++) t[b] = view.getFloat64(HEADER_BYTES + 8 * b, true);
  const minMax = new Float32Array(nBuckets * N_SERIES * 2);
  let off = HEADER_BYTES + 8 * nBuckets;
  let k = 0;
  for (let b = 0; b < nBuckets; b++) {
    for (let s = 0; s < nSeries; s++) {
      if (s < N_SERIES) {
        minMax[k++] = view.getFloat32(off, true);
        minMax[k++] = view.getFloat32(off + 4, true);
      }
      off += 8;
    }
  }
  return { nBuckets, t, minMax };
}

export interface Latency {
  p50_us?: number;
  p99_us?: number;
  p999_us?: number;
  max_us?: number;
  count?: number;
}

export interface ModelInfo {
  name: string;
  state: string;
  kind?: string;
  features?: string[];
  error?: string;
  units?: string;
  size_bytes?: number;
}

/** The fields of the status object the page shows; everything optional (shown as "–"). */
export interface Status {
  loop_alive?: boolean;
  mode?: string;
  clock?: string;
  rate_hz?: number;
  step?: number;
  fallbacks?: number;
  deadline_misses?: number;
  scheduling?: string;
  recorder?: string;
  telemetry_drops?: number;
  active_model?: ModelInfo | null;
  inference_latency?: Latency;
  round_trip_latency?: Latency;
  predictions?: number;
  uptime_s?: number;
  server_version?: string;
  token_required?: boolean;
}

/** Enum words as the page compares them: "MODEL_STATE_ACTIVE" and "active" both give "active". */
export function normalizeState(s: unknown): string {
  if (typeof s !== "string") return "unknown";
  return s.toLowerCase().replace(/^model_state_/, "");
}

export function normalizeModel(m: unknown): ModelInfo | null {
  if (!m || typeof m !== "object") return null;
  const o = m as Record<string, unknown>;
  if (typeof o.name !== "string" || o.name === "") return null;
  return {
    name: o.name,
    state: normalizeState(o.state),
    kind: typeof o.kind === "string" ? o.kind : undefined,
    features: Array.isArray(o.features) ? o.features.map(String) : undefined,
    error: typeof o.error === "string" && o.error !== "" ? o.error : undefined,
    units: typeof o.units === "string" ? o.units : undefined,
    size_bytes: typeof o.size_bytes === "number" ? o.size_bytes : undefined,
  };
}

/** Accepts the status object (plain or with `type: "status"`) and keeps the known fields. */
export function normalizeStatus(raw: unknown): Status {
  if (!raw || typeof raw !== "object") return {};
  const o = raw as Record<string, unknown>;
  const st: Status = { ...(o as Status) };
  st.active_model = normalizeModel(o.active_model);
  return st;
}

/** `/api/models` answers a list; a `{ models: [...] }` wrapper (the gRPC shape) is accepted too. */
export function normalizeModels(raw: unknown): ModelInfo[] {
  const list = Array.isArray(raw) ? raw : raw && typeof raw === "object" && Array.isArray((raw as { models?: unknown }).models) ? (raw as { models: unknown[] }).models : [];
  return list.map(normalizeModel).filter((m): m is ModelInfo => m !== null);
}
