// The page: wires the telemetry connection, the history store, the plots, the live figures, the
// model list and the experiment controls together. The plots are drawn in a requestAnimationFrame
// callback asked for at most DRAW_FPS times a second, and only when something new is to be drawn
// (new data, a view change); a hidden tab draws nothing (the browser runs no animation frames)
// and asks the server for one telemetry frame a second instead of DRAW_FPS. The WebSocket only
// appends to the store, so pausing the plots never stops data reception.
import "uplot/dist/uPlot.min.css";
import "./style.css";
import { api, ApiError, getToken, setToken, setTokenPrompt, wsProtocols, type ExperimentRequest } from "./api";
import { TelemetryConnection, type ConnState } from "./connection";
import { ModelNames, modelRuns, type ModelRun } from "./modelruns";
import { decodeFrame, normalizeModels, normalizeStatus, SERIES, type ModelInfo, type Status } from "./protocol";
import { readColumns, TelemetryStore, toCsv, type Columns } from "./store";
import { TimePlot, type PlotDef } from "./timeplots";
import { enclosedArea, XYPlot, type XYTrace } from "./xyplot";

const $ = <T extends HTMLElement = HTMLElement>(id: string): T => {
  const el = document.getElementById(id);
  if (!el) throw new Error(`#${id} missing`);
  return el as T;
};

// Colours: Okabe-Ito, darkened where needed for contrast on white.
const C = { cmd: "#111827", res: "#0072b2", pred: "#d55e00", truth: "#009e73", felt: "#56b4e9", prev: "#cc79a7", depth: "#7b3294", vel: "#0072b2", acc: "#a6611a" };

const S = Object.fromEntries(SERIES.map((n, i) => [n, i])) as Record<(typeof SERIES)[number], number>;
/** Unit conversion per series for display: depth in mm, velocity in mm/s. */
const DISPLAY_SCALE = SERIES.map((_, i) => (i === S.position_x || i === S.velocity ? 1000 : 1));

const PLOTS: PlotDef[] = [
  {
    id: "force",
    title: "Force",
    yLabel: "force (N)",
    height: 250,
    signals: [
      { series: S.F_ref, label: "command F_ref", short: "F_ref", unit: "N", color: C.cmd, dash: [6, 4] },
      { series: S.rtob_force, label: "RFOB response", short: "F_res", unit: "N", color: C.res },
      { series: S.F_pred, label: "predicted", short: "F_pred", unit: "N", color: C.pred },
      // The simulated object's own force: what a model of the object predicts, so F_pred is
      // compared with this one. The felt force F_true is what pushes the probe from outside:
      // with the simulated hand, the hand's force, which also carries the bench's friction (up
      // to 1 N while the probe rests) and the motor's mass; without a hand, the object's again.
      { series: S.F_object, label: "object (sim)", short: "F_object", unit: "N", color: C.truth },
      { series: S.F_true, label: "felt (sim)", short: "F_true", unit: "N", color: C.felt, dash: [2, 3] },
      // The force the model was given as its previous one (F(t-1)): beside F_res it shows what a
      // feedback model saw. Off by default (at plot resolution it lies on the RFOB response).
      { series: S.f_previous, label: "previous F(t-1)", short: "F_prev", unit: "N", color: C.prev, hidden: true },
    ],
  },
  {
    id: "depth",
    title: "Compression depth",
    yLabel: "depth (mm)",
    height: 170,
    signals: [{ series: S.position_x, label: "depth x", short: "x", unit: "mm", color: C.depth }],
  },
  {
    id: "motion",
    title: "Velocity and acceleration",
    yLabel: "velocity (mm/s)",
    y2Label: "acceleration (m/s²)",
    height: 190,
    signals: [
      { series: S.velocity, label: "velocity", short: "v", unit: "mm/s", color: C.vel },
      { series: S.acceleration, label: "acceleration (right axis)", short: "a", unit: "m/s²", color: C.acc, scale: "y2" },
    ],
  },
];

// ---------------------------------------------------------------------------------------------
// State

const store = new TelemetryStore(1 << 18);
let paused = false;
/** Frozen view [t0, t1] while paused or zoomed; null = live rolling window. */
let frozen: [number, number] | null = null;
let windowS = 10;
let xyWindowS = 20;
let dirty = true;
let status: Status = {};
let lastStatusAt = 0;
let lastDataAt = 0;
let conn: ConnState = "connecting";
let retryAt = 0;
let frames = 0;
let badFrames = 0;
let models: ModelInfo[] = [];
/** The names of the model ids in the telemetry, learnt from the model list and the status. */
const modelNames = new ModelNames();
/** Which model drew each stretch of the shown range (force plot's strip and readout). */
let shownRuns: ModelRun[] = [];
const frameDeltas: number[] = [];
const drawTimes: number[] = [];
const FRAME_LOG = 2000;
let lastRaf = 0;
/** Most plot draws per second: `?fps=N` in the page's address (1-60), default 30. */
const DRAW_FPS = ((v: number) => (Number.isFinite(v) && v >= 1 ? Math.min(60, Math.round(v)) : 30))(
  Number(new URLSearchParams(location.search).get("fps")),
);
/** Telemetry frames per second asked of the server while the tab is hidden. */
const HIDDEN_FPS = 1;
let drawRequested = false;
let dataFramesThisSecond = 0;
let rafThisSecond = 0;
let secondStart = performance.now();

// ---------------------------------------------------------------------------------------------
// Messages

function log(text: string, kind: "ok" | "warn" | "err" | "" = ""): void {
  const li = document.createElement("li");
  li.textContent = `${new Date().toLocaleTimeString()} ${text}`;
  if (kind) li.className = kind;
  const ol = $("log");
  ol.prepend(li);
  while (ol.children.length > 50) ol.lastElementChild?.remove();
}

// ---------------------------------------------------------------------------------------------
// Plots

const syncKey = "haptics-time";
const timePlots: TimePlot[] = PLOTS.map((def) => {
  const plot = new TimePlot(def, $(`plot-${def.id}`), syncKey, {
    onZoom: (t0, t1) => {
      frozen = [Math.min(t0, t1), Math.max(t0, t1)];
      setPaused(true, "zoomed");
    },
    onResetZoom: () => goLive(),
    onWheel: (t, dir, panOnly) => wheel(t, dir, panOnly),
    readoutExtra: def.id === "force" ? (cols, i) => `model ${modelAt(cols, i)}` : undefined,
  }, document.getElementById(`readout-${def.id}`));
  const fs = $(`toggles-${def.id}`);
  def.signals.forEach((sig, k) => {
    const lab = document.createElement("label");
    lab.style.setProperty("--c", sig.color);
    const cb = document.createElement("input");
    cb.type = "checkbox";
    cb.checked = plot.isVisible(k);
    cb.id = `toggle-${def.id}-${sig.series}`;
    cb.dataset.series = SERIES[sig.series];
    cb.addEventListener("change", () => {
      plot.setVisible(k, cb.checked);
      dirty = true;
    });
    const sw = document.createElement("span");
    sw.className = "sw";
    sw.setAttribute("aria-hidden", "true");
    if (sig.dash) sw.style.background = `repeating-linear-gradient(90deg, ${sig.color} 0 5px, transparent 5px 8px)`;
    const txt = document.createElement("span");
    txt.textContent = sig.label;
    const nd = document.createElement("span");
    nd.className = "nodata";
    nd.id = `nodata-${SERIES[sig.series]}`;
    lab.append(cb, sw, txt, nd);
    fs.append(lab);
  });
  return plot;
});

const xy = new XYPlot($<HTMLCanvasElement>("xy"), "compression depth (mm)", "force (N)");
let xyPoints: { x: number[]; y: number[]; pred: number[] } = { x: [], y: [], pred: [] };

function layout(): void {
  // The time plots share the height left in the window (in their default proportions), so the
  // page needs no scrolling to see all three; below a minimum they keep their default heights.
  const top = $("plots").getBoundingClientRect().top + window.scrollY;
  const chrome = timePlots.length * 52 + 16 + $("model-strip").offsetHeight;
  const avail = window.innerHeight - top - chrome;
  const total = PLOTS.reduce((a, d) => a + d.height, 0);
  const k = Math.max(1, avail / total);
  for (const p of timePlots) {
    const host = $(`plot-${p.def.id}`);
    p.setSize(Math.max(300, host.clientWidth), Math.round(p.def.height * k));
  }
  const c = $("xy").parentElement as HTMLElement;
  const w = c.clientWidth - 20;
  xy.setSize(w, Math.min(420, Math.max(220, w * 0.95)));
  dirty = true;
}
new ResizeObserver(() => layout()).observe($("plots"));
window.addEventListener("resize", layout);

function viewRange(): [number, number] | null {
  if (frozen) return frozen;
  const last = store.lastTime();
  if (!Number.isFinite(last)) return null;
  return [last - windowS, last];
}

let lastCols: Columns | null = null;
/** The time range [t0, t1] of the last drawn frame (the test hook compares it with the view). */
let lastDrawn: [number, number] | null = null;

function render(): void {
  const r = viewRange();
  if (!r) {
    lastCols = readColumns(store, 0, -1, 1, DISPLAY_SCALE);
    lastDrawn = null;
    for (const p of timePlots) p.update(lastCols, 0, 1);
    xy.draw([]);
    xyPoints = { x: [], y: [], pred: [] };
    renderModelStrip([], 0, 1);
    return;
  }
  const [t0, t1] = r;
  const width = Math.max(...timePlots.map((p) => p.u.bbox.width / (window.devicePixelRatio || 1)), 300);
  const cols = readColumns(store, t0, t1, Math.round(width), DISPLAY_SCALE);
  lastCols = cols;
  lastDrawn = [t0, t1];
  for (const p of timePlots) p.update(cols, t0, t1);
  for (const name of ["F_pred", "F_object", "F_true"] as const) {
    const s = S[name];
    const has = cols.max[s].some((v) => v !== null);
    const nd = document.getElementById(`nodata-${name}`);
    const want = has ? "" : "(none)";
    // Only touch the DOM on a change: a write per frame would cost a style and layout pass.
    if (nd && nd.textContent !== want) nd.textContent = want;
  }
  renderXY(t1);
  renderModelStrip(modelRuns(cols, S.model_id, t1), t0, t1);
  const info = frozen
    ? `${paused && pauseReason === "zoomed" ? "Zoomed" : "Paused"}: ${t0.toFixed(2)}–${t1.toFixed(2)} s`
    : `Live: last ${windowS} s`;
  const vi = $("view-info");
  if (vi.textContent !== info) vi.textContent = info;
}

/** The model that drew column `i` (its name; "no model" where none did). */
function modelAt(cols: Columns, i: number): string {
  const a = cols.min[S.model_id][i];
  const b = cols.max[S.model_id][i];
  if (a === null || b === null) return "–";
  return a === b ? modelNames.name(a) : `${modelNames.name(a)}…${modelNames.name(b)}`;
}

let stripBox = "";
/**
 * The strip under the force plot: one labelled segment per run of a model, lined up with the
 * plot's time axis. Its elements are kept and only what changed is written (in the live view the
 * segments slide every frame; a write that changes nothing costs no style or layout pass).
 */
function renderModelStrip(runs: ModelRun[], t0: number, t1: number): void {
  shownRuns = runs;
  const strip = $("model-strip");
  const bbox = timePlots[0].u.bbox;
  const dpr = window.devicePixelRatio || 1;
  const box = `${bbox.left / dpr}px ${bbox.width / dpr}px`;
  if (box !== stripBox) {
    stripBox = box;
    strip.style.marginLeft = `${bbox.left / dpr}px`;
    strip.style.width = `${bbox.width / dpr}px`;
  }
  while (strip.children.length > runs.length) strip.lastElementChild?.remove();
  while (strip.children.length < runs.length) strip.append(document.createElement("span"));
  const span = t1 - t0 || 1;
  runs.forEach((r, k) => {
    const seg = strip.children[k] as HTMLElement;
    const name = modelNames.name(r.id);
    const a = Math.max(0, (r.t0 - t0) / span);
    const b = Math.min(1, (r.t1 - t0) / span);
    const set = (el: HTMLElement, key: "left" | "width", v: string) => {
      if (el.style[key] !== v) el.style[key] = v;
    };
    set(seg, "left", `${(a * 100).toFixed(2)}%`);
    set(seg, "width", `${(Math.max(0, b - a) * 100).toFixed(2)}%`);
    const cls = r.id === 0 ? "run none" : r.id === null ? "run swap" : "run";
    if (seg.className !== cls) seg.className = cls;
    const text = r.id === null ? "" : name;
    if (seg.textContent !== text) seg.textContent = text;
    // The name in full for a pointer resting on a segment too narrow for it.
    if (seg.title !== name) seg.title = name;
  });
}

/** Force-depth points of the last xyWindowS seconds ending at t1, at most ~1500 points. */
function renderXY(t1: number): void {
  const i0 = store.lowerBound(t1 - xyWindowS);
  const i1 = store.lowerBound(t1 + 1e-9);
  const n = i1 - i0;
  const group = Math.max(1, Math.ceil(n / 1500));
  const x: number[] = [];
  const y: number[] = [];
  const pred: number[] = [];
  const sx = S.position_x;
  const sf = S.rtob_force;
  const sp = S.F_pred;
  for (let i = i0; i < i1; i += group) {
    const e = Math.min(i1, i + group);
    let ax = 0;
    let af = 0;
    let ap = 0;
    let cnt = 0;
    for (let j = i; j < e; j++) {
      ax += (store.min(j, sx) + store.max(j, sx)) / 2;
      af += (store.min(j, sf) + store.max(j, sf)) / 2;
      ap += (store.min(j, sp) + store.max(j, sp)) / 2;
      cnt++;
    }
    x.push((ax / cnt) * 1000);
    y.push(af / cnt);
    pred.push(ap / cnt);
  }
  xyPoints = { x, y, pred };
  const traces: XYTrace[] = [{ label: "RFOB response", color: C.res, x, y }];
  if (pred.some(Number.isFinite)) traces.push({ label: "predicted", color: C.pred, x, y: pred, dash: [5, 3] });
  xy.draw(traces);
}

function frame(now: number): void {
  drawRequested = false;
  if (lastRaf) {
    frameDeltas.push(now - lastRaf);
    if (frameDeltas.length > FRAME_LOG) frameDeltas.splice(0, frameDeltas.length - FRAME_LOG);
  }
  lastRaf = now;
  rafThisSecond++;
  if (dirty) {
    dirty = false;
    const t = performance.now();
    render();
    drawTimes.push(performance.now() - t);
    if (drawTimes.length > FRAME_LOG) drawTimes.splice(0, drawTimes.length - FRAME_LOG);
  }
}

/** The draw clock: at most DRAW_FPS animation frames a second, none while nothing is new. */
function drawTick(): void {
  if (dirty && !drawRequested && document.visibilityState === "visible") {
    drawRequested = true;
    requestAnimationFrame(frame);
  }
}

function everySecond(): void {
  const now = performance.now();
  $("fps").textContent = `${Math.round((rafThisSecond * 1000) / (now - secondStart))} fps · ${Math.round((dataFramesThisSecond * 1000) / (now - secondStart))} data/s`;
  rafThisSecond = 0;
  dataFramesThisSecond = 0;
  secondStart = now;
  updateConnView();
  // The server pushes the status about twice a second; should those text frames stop while
  // the socket is open, ask for it instead so the figures never go stale silently.
  if (conn === "open" && now - lastStatusAt > 2000) void pollStatus();
}

/** The telemetry rate the server should send at now: what the page draws. */
const wantedFps = () => (document.visibilityState === "visible" ? DRAW_FPS : HIDDEN_FPS);

// ---------------------------------------------------------------------------------------------
// Pause, zoom, window, clear, export

let pauseReason: "user" | "zoomed" = "user";

function setPaused(p: boolean, reason: "user" | "zoomed" = "user"): void {
  paused = p;
  pauseReason = reason;
  if (p && !frozen) frozen = viewRange();
  if (!p) frozen = null;
  const b = $("pause");
  b.setAttribute("aria-pressed", String(p));
  b.textContent = p ? "Resume" : "Pause";
  dirty = true;
}

function goLive(): void {
  setPaused(false);
}

function setWindow(s: number): void {
  windowS = s;
  ($("window") as HTMLSelectElement).value = String(s);
  if (frozen) {
    // Keep the right edge, change the span.
    frozen = [frozen[1] - s, frozen[1]];
  }
  dirty = true;
}

function stepWindow(dir: 1 | -1): void {
  const opts = [...($("window") as HTMLSelectElement).options].map((o) => Number(o.value));
  const i = opts.indexOf(windowS);
  const j = Math.max(0, Math.min(opts.length - 1, (i < 0 ? 2 : i) + dir));
  setWindow(opts[j]);
}

function pan(dir: 1 | -1): void {
  const r = viewRange();
  if (!r) return;
  if (!paused) setPaused(true);
  const span = r[1] - r[0];
  const f = frozen ?? r;
  frozen = [f[0] + dir * span * 0.2, f[1] + dir * span * 0.2];
  dirty = true;
}

/** Wheel zoom around the time under the cursor (the view freezes there), or pan with shift. */
function wheel(t: number, dir: number, panOnly: boolean): void {
  const r = viewRange();
  if (!r || !dir || !Number.isFinite(t)) return;
  const span = r[1] - r[0];
  if (panOnly) {
    frozen = [r[0] + dir * span * 0.1, r[1] + dir * span * 0.1];
  } else {
    const f = dir > 0 ? 1.25 : 0.8;
    const newSpan = Math.min(600, Math.max(0.002, span * f));
    const k = (t - r[0]) / span;
    frozen = [t - k * newSpan, t + (1 - k) * newSpan];
  }
  setPaused(true, "zoomed");
}

$("pause").addEventListener("click", () => setPaused(!paused));
$("live").addEventListener("click", goLive);
$("window").addEventListener("change", (e) => setWindow(Number((e.target as HTMLSelectElement).value)));
$("xy-window").addEventListener("change", (e) => {
  xyWindowS = Number((e.target as HTMLSelectElement).value);
  dirty = true;
});
$("clear").addEventListener("click", () => {
  store.clear();
  frozen = paused ? null : frozen;
  if (paused) setPaused(false);
  dirty = true;
  log("History cleared");
});
$("export").addEventListener("click", () => {
  const r = viewRange();
  if (!r) {
    log("Nothing to export yet", "err");
    return;
  }
  const csv = toCsv(store, r[0], r[1], SERIES);
  const blob = new Blob([csv], { type: "text/csv" });
  const a = document.createElement("a");
  a.href = URL.createObjectURL(blob);
  a.download = `haptics_${r[0].toFixed(3)}-${r[1].toFixed(3)}s.csv`;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10_000);
  log(`Exported ${csv.split("\n").length - 2} rows (${r[0].toFixed(2)}–${r[1].toFixed(2)} s)`, "ok");
});

document.addEventListener("keydown", (e) => {
  const tag = (e.target as HTMLElement).tagName;
  if (e.ctrlKey || e.metaKey || e.altKey) return;
  if (tag === "INPUT" || tag === "SELECT" || tag === "TEXTAREA" || (e.target as HTMLElement).closest("dialog")) return;
  if (e.key === " " && tag !== "BUTTON") {
    e.preventDefault();
    setPaused(!paused);
  } else if (e.key === "Escape") goLive();
  else if (e.key === "+" || e.key === "=") stepWindow(1);
  else if (e.key === "-" || e.key === "_") stepWindow(-1);
  else if (e.key === "ArrowLeft" && tag !== "BUTTON") pan(-1);
  else if (e.key === "ArrowRight" && tag !== "BUTTON") pan(1);
});

// ---------------------------------------------------------------------------------------------
// Connection state and live figures

const fmtInt = (v: number | undefined): string => (typeof v === "number" && Number.isFinite(v) ? Math.round(v).toLocaleString("en-US") : "–");
const fmtUs = (v: number | undefined): string => (typeof v === "number" && Number.isFinite(v) ? (v >= 100 ? v.toFixed(0) : v.toFixed(1)) : "–");

function setText(id: string, text: string, cls = ""): void {
  const el = $(id);
  if (el.textContent !== text) el.textContent = text;
  el.className = cls;
}

function updateFigures(): void {
  const s = status;
  // A board failure (each put the motor at 0 A) stays on the loop's line with its reason.
  const boardFault = (s.board_faults ?? 0) > 0 ? `, board fault ×${s.board_faults}: ${s.board_fault ?? ""}` : "";
  setText("f-loop", s.loop_alive === undefined ? "–" : s.loop_alive ? `alive${[s.clock, s.board].filter(Boolean).map((x) => `, ${x}`).join("")}${boardFault}` : "gone", s.loop_alive === false || boardFault ? "bad" : s.loop_alive ? "ok" : "");
  setText("f-rate", typeof s.rate_hz === "number" && s.loop_alive !== false ? (s.rate_hz >= 1000 ? `${(s.rate_hz / 1000).toFixed(3)} kHz` : `${s.rate_hz.toFixed(1)} Hz`) : "–");
  setText("f-steps", fmtInt(s.step));
  // A histogram with no samples yet has nothing to say (its zeros are not latencies).
  const lat = (l: Status["round_trip_latency"]) => (l && l.count !== 0 ? `${fmtUs(l.p50_us)} / ${fmtUs(l.p99_us)} / ${fmtUs(l.p999_us)} µs` : "–");
  setText("f-rtt", lat(s.round_trip_latency));
  setText("f-inf", lat(s.inference_latency));
  setText("f-miss", fmtInt(s.deadline_misses), (s.deadline_misses ?? 0) > 0 ? "bad" : "");
  setText("f-fallback", fmtInt(s.fallbacks), (s.fallbacks ?? 0) > 0 ? "bad" : "");
  // The degradation ladder: anything below "on time" is counted; the fallback rung is the bad one.
  const rungs = [s.on_time, s.late_one, s.held, s.fallback];
  setText("f-ladder", rungs.every((v) => v === undefined) ? "–" : rungs.map(fmtInt).join(" / "), (s.fallback ?? 0) > 0 ? "bad" : (s.late_one ?? 0) + (s.held ?? 0) > 0 ? "warn" : "");
  setText("f-transition", typeof s.max_transition_step_n === "number" ? `${s.max_transition_step_n.toFixed(3)} N` : "–", (s.max_transition_step_n ?? 0) > 0.05 ? "bad" : "");
  // The passivity layer: on/off, the energy the object holds (received / returned), its damping.
  const pa = s.passivity;
  setText("f-passivity", pa ? `${pa.on ? "on" : "off (observing)"}: ${(pa.energy_j ?? 0).toFixed(3)} J (in ${(pa.received_j ?? 0).toFixed(3)} / out ${(pa.returned_j ?? 0).toFixed(3)}), max ${(pa.damping_ns_per_m ?? 0).toFixed(1)} N s/m, ${fmtInt(pa.active_steps)} steps` : "–", (pa?.returned_j ?? 0) > (pa?.received_j ?? 0) ? "bad" : (pa?.active_steps ?? 0) > 0 ? "warn" : "");
  setText("f-corrupt", fmtInt(s.corrupt), (s.corrupt ?? 0) > 0 ? "bad" : "");
  setText("f-model", s.active_model ? `${s.active_model.name}${s.active_model.kind ? ` (${s.active_model.kind})` : ""}` : s.loop_alive === undefined ? "–" : "none (fallback)");
  const expDetail = s.mode && s.mode !== "idle" ? [s.experiment_cycle ? `cycle ${s.experiment_cycle}` : "", s.experiment_phase ?? ""].filter(Boolean).join(", ") : "";
  setText("f-mode", s.mode ? `${s.mode}${expDetail ? ` (${expDetail})` : ""}` : "–");
  setText("f-drops", fmtInt(s.telemetry_drops));
  // A failed recording is said where the person looks, in red, with what was saved.
  setText("f-recorder", s.recorder ? (s.recorder_failed ? `RECORDER ERROR: ${s.recorder}` : s.recorder) : "–", s.recorder_failed ? "bad" : "");
  const up = typeof s.uptime_s === "number" ? `up ${formatDuration(s.uptime_s)}` : "";
  setText("f-server", [s.server_version ? `v${s.server_version}` : "", up].filter(Boolean).join(", ") || "–");
}

function formatDuration(s: number): string {
  if (s < 120) return `${Math.round(s)} s`;
  if (s < 7200) return `${Math.round(s / 60)} min`;
  return `${(s / 3600).toFixed(1)} h`;
}

type ViewState = "connecting" | "live" | "loop-gone" | "server-gone" | "no-data";

function viewState(now: number): ViewState {
  if (conn === "closed") return "server-gone";
  // Open but no status yet: still finding out whether a loop is there.
  if (conn === "connecting" || lastStatusAt === 0) return "connecting";
  if (status.loop_alive === false) return "loop-gone";
  if (now - lastStatusAt > 5000 && now - lastDataAt > 2000) return "no-data";
  if (now - lastDataAt > 2000) return "no-data";
  return "live";
}

let shownState: ViewState | null = null;
function updateConnView(): void {
  const now = performance.now();
  const st = viewState(now);
  const el = $("conn");
  el.dataset.state = st;
  const banner = $("banner");
  const retry = $("retry");
  let text = "";
  let bannerText = "";
  switch (st) {
    case "connecting":
      text = "Connecting…";
      break;
    case "live":
      text = "Live";
      break;
    case "loop-gone":
      text = "Loop gone";
      bannerText = "The real-time loop is gone: no rt-loop is attached to the server. The plots stay as they were; data resumes here when a loop attaches again.";
      break;
    case "no-data":
      text = "Connected, no data";
      bannerText = "Connected to the server, but no telemetry has arrived for over 2 s.";
      break;
    case "server-gone": {
      const secs = Math.max(0, Math.ceil((retryAt - now) / 1000));
      text = "Server gone";
      bannerText = `The server is gone (the connection closed). Reconnecting${secs > 0 ? ` in ${secs} s` : "…"}; the page recovers by itself, no reload needed.`;
      break;
    }
  }
  setText("conn-text", text);
  retry.hidden = st !== "server-gone";
  banner.hidden = bannerText === "";
  banner.dataset.kind = st;
  if (banner.textContent !== bannerText) banner.textContent = bannerText;
  if (st !== shownState) {
    if (shownState !== null) log(`Connection: ${text}`, st === "live" ? "ok" : st === "connecting" ? "" : "err");
    shownState = st;
  }
}

function onStatus(raw: unknown): void {
  const prevModel = status.active_model?.name;
  status = normalizeStatus(raw);
  modelNames.learn([status.active_model]);
  lastStatusAt = performance.now();
  updateFigures();
  updateConnView();
  if (status.active_model?.name !== prevModel) void refreshModels();
  if (status.token_required && !getToken()) $("token-btn").classList.add("primary");
}

const wsUrl = () => `${location.protocol === "https:" ? "wss:" : "ws:"}//${location.host}/ws/telemetry?fps=${wantedFps()}`;
const connection = new TelemetryConnection(wsUrl, {
  onBinary(buf) {
    try {
      store.append(decodeFrame(buf));
      frames++;
      dataFramesThisSecond++;
      lastDataAt = performance.now();
      if (!paused) dirty = true;
    } catch (e) {
      badFrames++;
      if (badFrames <= 5 || badFrames % 1000 === 0) log(`Bad telemetry frame #${badFrames}: ${(e as Error).message}`, "err");
    }
  },
  onText(text) {
    try {
      const o = JSON.parse(text);
      if (o && (o.type === "status" || o.type === undefined)) onStatus(o);
    } catch {
      log("Unreadable text frame from the server", "err");
    }
  },
  onState(st, info) {
    // Refused before it opened (a server that needs a token for the telemetry socket too): the
    // status over HTTP says whether a token is wanted, and the token button lights up.
    if (st === "closed" && conn !== "open") void pollStatus();
    conn = st;
    if (st === "closed") retryAt = performance.now() + (info.retryInMs ?? 0);
    if (st === "open") {
      // Fresh after a reconnect: the status and the model list may have changed meanwhile.
      void pollStatus();
      void refreshModels();
    }
    updateConnView();
  },
}, wsProtocols);
$("retry").addEventListener("click", () => connection.retryNow());
document.addEventListener("visibilitychange", () => {
  connection.send(JSON.stringify({ fps: wantedFps() }));
  drawTick();
});

async function pollStatus(): Promise<void> {
  try {
    onStatus(await api.status());
  } catch (e) {
    // Refused for want of the token (the page was opened without `#token=...`): the token
    // button asks for it. Anything else: the WebSocket state says what is wrong.
    if (e instanceof ApiError && e.status === 401) $("token-btn").classList.add("primary");
  }
}

// ---------------------------------------------------------------------------------------------
// Models

async function refreshModels(force = false): Promise<void> {
  try {
    models = normalizeModels(await api.models());
    modelNames.learn(models);
    dirty = true; // the model strip may now name an id it showed by number
    renderModels(force);
  } catch (e) {
    if (conn === "open") log(`Model list: ${(e as Error).message}`, "err");
  }
}

/** What the model rows were last built from: a refresh that brings the same list and active
 * model (most of the 5 s safety-net refreshes) leaves the rows, and a keyboard user's focus on
 * one of their buttons, as they are. */
let modelsShown = "";

function renderModels(force = false): void {
  const body = $("models-body");
  const shown = JSON.stringify([models, status.active_model?.name ?? null]);
  if (!force && shown === modelsShown) return;
  modelsShown = shown;
  // A rebuild replaces the buttons: give the focus back to the same model's button, so a
  // keyboard user's Tab and Enter stay where they were (a replaced element takes the focus
  // away to the page's body).
  const focused = document.activeElement;
  const focusedModel = focused && body.contains(focused) ? focused.closest("tr")?.dataset.model : undefined;
  body.replaceChildren();
  if (!models.length) {
    const tr = document.createElement("tr");
    tr.innerHTML = `<td colspan="5" class="muted">No models in the server's model directory</td>`;
    body.append(tr);
    return;
  }
  const activeName = status.active_model?.name;
  for (const m of models) {
    const tr = document.createElement("tr");
    tr.dataset.model = m.name;
    const active = m.state === "active" || m.name === activeName;
    const name = document.createElement("td");
    name.className = "name";
    name.textContent = m.name;
    if (m.features?.length) name.title = `features: ${m.features.join(", ")}`;
    const state = document.createElement("td");
    state.textContent = active ? "active" : m.state;
    state.className = `state-${active ? "active" : m.state}`;
    if (m.error) state.title = m.error;
    const kind = document.createElement("td");
    kind.textContent = m.kind ?? "";
    if (m.reference_steps) {
      // the server computed the model's reference steps as its export did (it refuses a
      // model where one differs): a mark, its meaning in the title
      const mark = document.createElement("span");
      mark.className = "checked";
      mark.textContent = " ✓";
      mark.title = `${m.reference_steps} reference steps computed on this server as at the model's export`;
      mark.setAttribute("aria-label", mark.title);
      kind.append(mark);
    }
    const cost = document.createElement("td");
    cost.className = "cost";
    const c = m.cost;
    const f = (v?: number): string => (v === undefined ? "–" : v.toFixed(1));
    cost.textContent = c ? `${f(c.export_p50_us)}/${f(c.export_p99_us)}${c.warmup_p50_us !== undefined ? ` (here ${f(c.warmup_p50_us)})` : ""}` : "–";
    cost.title = "µs per call: p50/p99 measured at export on the exporting machine; (here: this server's warm-up median)";
    const act = document.createElement("td");
    const b = document.createElement("button");
    b.type = "button";
    b.textContent = active ? "Active" : "Activate";
    b.disabled = active;
    b.setAttribute("aria-label", active ? `${m.name} is the active model` : `Activate model ${m.name}`);
    b.addEventListener("click", () => void swapModel(m, b));
    act.append(b);
    tr.append(name, state, kind, cost, act);
    body.append(tr);
    if (m.name === focusedModel) b.focus();
  }
}

async function swapModel(m: ModelInfo, button: HTMLButtonElement): Promise<void> {
  button.disabled = true;
  button.textContent = "Swapping…";
  try {
    if (m.state === "available" || m.state === "failed") {
      log(`Loading ${m.name}…`);
      await api.load(m.name);
    }
    const r = (await api.activate(m.name)) as { effective_step?: number; warnings?: string[] };
    log(`Active model: ${m.name}${r && typeof r.effective_step === "number" ? ` from step ${r.effective_step}` : ""}`, "ok");
    // served anyway, but the user should know (e.g. features of other filters than the loop's)
    for (const w of r?.warnings ?? []) log(`Warning: ${m.name}: ${w}`, "warn");
  } catch (e) {
    log(`Could not activate ${m.name}: ${(e as Error).message}`, "err");
  }
  await pollStatus();
  // Rebuilt even if nothing changed (a refused swap): the button says "Swapping…" until then.
  await refreshModels(true);
}
$("models-refresh").addEventListener("click", () => void refreshModels(true));

// ---------------------------------------------------------------------------------------------
// Experiment

const expKind = $<HTMLSelectElement>("exp-kind");
function syncExpForm(): void {
  const ramp = expKind.value !== "reproduction";
  for (const id of ["exp-rate", "exp-cycles", "exp-fmax", "exp-fstep"]) ($(id) as HTMLInputElement).disabled = !ramp;
}
expKind.addEventListener("change", syncExpForm);
syncExpForm();

$("exp-form").addEventListener("submit", (e) => {
  e.preventDefault();
  const kind = expKind.value as ExperimentRequest["kind"];
  const req: ExperimentRequest = { kind };
  if (kind !== "reproduction") {
    const num = (id: string) => Number(($(id) as HTMLInputElement).value);
    req.ramp_rate = num("exp-rate");
    req.cycles = Math.round(num("exp-cycles"));
    req.f_max_start = num("exp-fmax");
    req.f_max_step = num("exp-fstep");
    const bad = Object.entries(req).filter(([k, v]) => k !== "kind" && !(typeof v === "number" && Number.isFinite(v) && v >= 0));
    if (bad.length) {
      log(`Experiment not started: ${bad.map(([k]) => k).join(", ")} must be numbers ≥ 0`, "err");
      return;
    }
  }
  void (async () => {
    try {
      await api.startExperiment(req);
      log(`Experiment started: ${kind}${req.ramp_rate ? ` at ${req.ramp_rate} N/s, ${req.cycles} cycles` : ""}`, "ok");
    } catch (err) {
      log(`Experiment not started: ${(err as Error).message}`, "err");
    }
    void pollStatus();
  })();
});
$("exp-stop").addEventListener("click", () => {
  void (async () => {
    try {
      await api.stopExperiment();
      log("Experiment stopped", "ok");
    } catch (err) {
      log(`Stop failed: ${(err as Error).message}`, "err");
    }
    void pollStatus();
  })();
});

// ---------------------------------------------------------------------------------------------
// Token prompt

const dlg = $<HTMLDialogElement>("token-dialog");
function promptToken(reason: string): Promise<string | null> {
  $("token-reason").textContent = reason;
  const input = $<HTMLInputElement>("token-input");
  input.value = getToken() ?? "";
  return new Promise((resolve) => {
    const done = (v: string | null) => {
      dlg.removeEventListener("close", onClose);
      resolve(v);
    };
    const onClose = () => done(dlg.returnValue === "ok" && input.value ? input.value : null);
    dlg.addEventListener("close", onClose);
    dlg.returnValue = "";
    dlg.showModal();
    input.focus();
  });
}
$("token-cancel").addEventListener("click", () => dlg.close("cancel"));
setTokenPrompt(promptToken);
$("token-btn").addEventListener("click", () => {
  void promptToken("The token is sent with changes (model swap, experiments) and kept for this tab only.").then((t) => {
    if (t !== null) {
      setToken(t);
      $("token-btn").classList.remove("primary");
      log("Token set for this tab", "ok");
      connection.retryNow();
    }
  });
});

// ---------------------------------------------------------------------------------------------
// Read-only test hook (used by web-ui/tests; harmless for people).

const copy = (a: (number | null)[] | number[]) => Array.from(a, (v) => (v === null ? NaN : v));
Object.defineProperty(window, "__haptics", {
  value: Object.freeze({
    /** What the time plots currently draw for a series: t and min/max (display units). */
    points(name: string) {
      const s = SERIES.indexOf(name as (typeof SERIES)[number]);
      if (s < 0 || !lastCols) return { t: [], min: [], max: [] };
      return { t: copy(lastCols.t), min: copy(lastCols.min[s]), max: copy(lastCols.max[s]) };
    },
    /** The force-depth plot's points (depth mm, RFOB force N) and their enclosed area (N·mm). */
    xy() {
      return { x: [...xyPoints.x], y: [...xyPoints.y], area: enclosedArea(xyPoints.x, xyPoints.y) };
    },
    /** Most plot draws per second (`?fps=`, default 30). */
    drawFps: DRAW_FPS,
    /** Deltas between the animation frames that were asked for to draw (ms), the last 2000. */
    frameTimes: () => [...frameDeltas],
    /** Time spent drawing each frame that had new data (ms), the last 2000. */
    drawTimes: () => [...drawTimes],
    get paused() {
      return paused;
    },
    get state() {
      return viewState(performance.now());
    },
    status: () => JSON.parse(JSON.stringify(status)),
    /** Shown time range [t0, t1] and whether it is frozen (paused or zoomed). */
    view: () => ({ range: viewRange(), frozen: frozen !== null, windowS, drawn: lastDrawn }),
    /** Which series each time plot shows (per-series toggles). */
    shown: () => Object.fromEntries(timePlots.flatMap((p) => p.def.signals.map((sig, k) => [SERIES[sig.series], p.isVisible(k)]))),
    /** The model strip: which model drew which stretch of the shown range (t0, t1 in s). */
    modelRuns: () => shownRuns.map((r) => ({ t0: r.t0, t1: r.t1, id: r.id, name: modelNames.name(r.id) })),
    counts: () => ({ frames, badFrames, buckets: store.appended, held: store.length, restarts: store.restarts, lastTime: store.lastTime() }),
  }),
});

// ---------------------------------------------------------------------------------------------
// Start

layout();
updateFigures();
updateConnView();
connection.start();
void refreshModels();
setInterval(() => {
  // A slow safety net beside the pushed status: keeps the model list right if it changed
  // through gRPC (hapticctl) without a change of active model.
  if (conn === "open") void refreshModels();
}, 5000);
setInterval(everySecond, 1000);
setInterval(drawTick, 1000 / DRAW_FPS);
drawTick();
