// Decoding of what infer-server sends (docs/web-protocol.md): binary telemetry frames of
// min/max buckets and the status object (the gRPC Status message as JSON).
import { SERIES } from "./vocab";

/**
 * The series of a telemetry frame, in the order the server writes them: the vocabulary's
 * (generated into vocab.ts from proto/'s `haptics_proto::series`), never a copy. `f_previous` is
 * F(t-1), the previous force the loop gives a model; `model_id` the id of the model whose answer
 * the loop used for each step (its min and max over a bucket differ where the model changed
 * inside it; 0: no model's answer).
 */
export { SERIES };
export type SeriesName = (typeof SERIES)[number];
export const N_SERIES = SERIES.length;
/**
 * Series every server sends: the protocol grows by appending series, and a frame from a server
 * that stops after these (one older than the page) reads the page's later series as NaN (shown
 * as "no data"), rather than being refused.
 */
export const MIN_SERIES = SERIES.indexOf("F_true") + 1;

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
 * Decodes one binary frame. Series beyond the N_SERIES the page knows are skipped (the protocol lets
 * the server add more later), series the frame lacks beyond MIN_SERIES are NaN; a frame that is
 * short, has the wrong magic or version, or has fewer than MIN_SERIES series is rejected with a
 * message that says which.
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
  if (nSeries < MIN_SERIES) throw new FrameError(`frame has ${nSeries} series, the page needs at least ${MIN_SERIES}`);
  const need = HEADER_BYTES + 8 * nBuckets + 8 * nBuckets * nSeries;
  if (buf.byteLength !== need) throw new FrameError(`frame of ${buf.byteLength} bytes, header says ${need}`);
  const t = new Float64Array(nBuckets);
  for (let b = 0; b < nBuckets; b++) t[b] = view.getFloat64(HEADER_BYTES + 8 * b, true);
  const minMax = new Float32Array(nBuckets * N_SERIES * 2);
  if (nSeries < N_SERIES) minMax.fill(NaN);
  const read = Math.min(nSeries, N_SERIES);
  let off = HEADER_BYTES + 8 * nBuckets;
  for (let b = 0; b < nBuckets; b++) {
    let k = b * N_SERIES * 2;
    for (let s = 0; s < nSeries; s++) {
      if (s < read) {
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

/** The passivity layer of the current (or last) run: whether its damper acts, the energy the
 * rendered object holds, received and returned (J, positive = into the object), the largest
 * damping it applied (N s/m), the steps it changed the force on. */
export interface Passivity {
  on?: boolean;
  energy_j?: number;
  received_j?: number;
  returned_j?: number;
  damping_ns_per_m?: number;
  active_steps?: number;
}

export interface ModelInfo {
  name: string;
  state: string;
  kind?: string;
  features?: string[];
  error?: string;
  units?: string;
  size_bytes?: number;
  /** The id the model's answers carry while it is active (its generation; 0: never active). */
  model_id?: number;
  /** What one call costs, us: the export's measurement (on the exporting machine, the model's
   * `haptics.cost`) and this server's warm-up median (docs/model-contract.md, "Cost"). */
  cost?: ModelCost;
  /** The reference steps (`haptics.reference`) the server computed as the model's export did
   * when it loaded it (0: it carries none, or it is not loaded). */
  reference_steps?: number;
}

export interface ModelCost {
  export_p50_us?: number;
  export_p99_us?: number;
  warmup_p50_us?: number;
}

/** `{"export": {"p50_us", "p99_us", ..}, "warmup": {"p50_us", ..}}` (the JSON API's `cost`, or
 * gRPC's `cost_json` string); undefined when nothing is known. */
export function normalizeCost(v: unknown): ModelCost | undefined {
  let o: unknown = v;
  if (typeof v === "string") {
    try {
      o = JSON.parse(v);
    } catch {
      return undefined;
    }
  }
  const c = o && typeof o === "object" ? (o as Record<string, Record<string, unknown> | null>) : null;
  if (!c) return undefined;
  const n = (part: string, key: string): number | undefined => {
    const x = c[part]?.[key];
    return typeof x === "number" ? x : undefined;
  };
  const cost = { export_p50_us: n("export", "p50_us"), export_p99_us: n("export", "p99_us"), warmup_p50_us: n("warmup", "p50_us") };
  return Object.values(cost).some((x) => x !== undefined) ? cost : undefined;
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
  /** Degradation ladder of the current (or last) run: steps rendered by the model's on-time
   * answer, by the previous step's answer one period late, by the held force, by the fallback. */
  on_time?: number;
  late_one?: number;
  held?: number;
  fallback?: number;
  /** Ring slots or indices the loop found corrupt. */
  corrupt?: number;
  /** Largest one-step change of the rendered force a ladder transition caused, N. */
  max_transition_step_n?: number;
  /** Board failures that ended a run (each at 0 A) and the last one's reason. */
  board_faults?: number;
  board_fault?: string;
  passivity?: Passivity;
  experiment_cycle?: number;
  experiment_phase?: string;
  board?: string;
  scheduling?: string;
  recorder?: string;
  /** The current (or last) run's recording failed: `recorder` says why and what was saved. */
  recorder_failed?: boolean;
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
    model_id: typeof o.model_id === "number" ? o.model_id : undefined,
    cost: normalizeCost(o.cost ?? o.cost_json),
    reference_steps: typeof o.reference_steps === "number" ? o.reference_steps : undefined,
  };
}

type Obj = Record<string, unknown>;
const obj = (v: unknown): Obj | null => (v && typeof v === "object" && !Array.isArray(v) ? (v as Obj) : null);
const num = (v: unknown): number | undefined => (typeof v === "number" ? v : undefined);
const str = (v: unknown): string | undefined => (typeof v === "string" ? v : undefined);
const bool = (v: unknown): boolean | undefined => (typeof v === "boolean" ? v : undefined);

/** `{ p50, p99, p999, max, count }` (the JSON API) or `{ p50_us, ... }` (gRPC names). */
function latency(v: unknown): Latency | undefined {
  const o = obj(v);
  if (!o) return undefined;
  return {
    p50_us: num(o.p50) ?? num(o.p50_us),
    p99_us: num(o.p99) ?? num(o.p99_us),
    p999_us: num(o.p999) ?? num(o.p999_us),
    max_us: num(o.max) ?? num(o.max_us),
    count: num(o.count),
  };
}

function passivity(v: unknown): Passivity | undefined {
  const o = obj(v);
  if (!o) return undefined;
  return {
    on: bool(o.on),
    energy_j: num(o.energy_j),
    received_j: num(o.received_j),
    returned_j: num(o.returned_j),
    damping_ns_per_m: num(o.damping_ns_per_m),
    active_steps: num(o.active_steps),
  };
}

/**
 * Reads the status object into the page's flat form. The server sends
 * `{ server: {...}, loop: {...}, active_model }` (docs/web-protocol.md); the flat gRPC `Status`
 * field names are accepted too, so a server speaking either works.
 */
export function normalizeStatus(raw: unknown): Status {
  const o = obj(raw);
  if (!o) return {};
  const server = obj(o.server);
  const loop = obj(o.loop);
  if (!server && !loop) {
    const st: Status = { ...(o as Status) };
    st.active_model = normalizeModel(o.active_model);
    return st;
  }
  const exp = obj(loop?.experiment);
  const expKind = str(exp?.kind);
  const running = bool(exp?.running);
  return {
    loop_alive: bool(loop?.alive),
    mode: expKind === undefined ? undefined : running === false ? "idle" : expKind,
    experiment_cycle: num(exp?.cycle),
    experiment_phase: str(exp?.phase),
    clock: str(loop?.clock),
    board: str(loop?.board),
    rate_hz: num(loop?.rate_hz),
    step: num(loop?.steps),
    fallbacks: num(loop?.fallbacks),
    deadline_misses: num(loop?.deadline_misses),
    on_time: num(loop?.on_time),
    late_one: num(loop?.late_one),
    held: num(loop?.held),
    fallback: num(loop?.fallback),
    corrupt: num(loop?.corrupt),
    max_transition_step_n: num(loop?.max_transition_step_n),
    board_faults: num(loop?.board_faults),
    board_fault: str(loop?.board_fault),
    passivity: passivity(loop?.passivity),
    scheduling: str(loop?.scheduling),
    recorder: str(loop?.recorder),
    recorder_failed: bool(loop?.recorder_failed),
    telemetry_drops: num(loop?.telemetry_drops),
    round_trip_latency: latency(loop?.latency_us),
    inference_latency: latency(server?.inference_latency_us),
    predictions: num(server?.predictions),
    uptime_s: num(server?.uptime_s),
    server_version: str(server?.version),
    token_required: bool(server?.token_required),
    active_model: normalizeModel(o.active_model),
  };
}

/** `/api/models` answers a list; a `{ models: [...] }` wrapper (the gRPC shape) is accepted too. */
export function normalizeModels(raw: unknown): ModelInfo[] {
  const list = Array.isArray(raw) ? raw : raw && typeof raw === "object" && Array.isArray((raw as { models?: unknown }).models) ? (raw as { models: unknown[] }).models : [];
  return list.map(normalizeModel).filter((m): m is ModelInfo => m !== null);
}
