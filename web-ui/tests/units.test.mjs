// Unit tests of the page's pure logic (frame decoding, the bucket store, per-pixel merging, CSV,
// status normalisation), compiled from src/ with Vite into a temporary folder and imported here.
import { before, describe, test } from "node:test";
import assert from "node:assert/strict";
import { mkdtemp, rm } from "node:fs/promises";
import { tmpdir } from "node:os";
import { dirname, join } from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";
import { build } from "vite";

const root = join(dirname(fileURLToPath(import.meta.url)), "..");
let m;

before(async () => {
  const out = await mkdtemp(join(tmpdir(), "haptics-units-"));
  await build({
    configFile: false,
    root,
    logLevel: "silent",
    build: { outDir: out, emptyOutDir: true, minify: false, lib: { entry: join(root, "tests", "units-entry.ts"), formats: ["es"], fileName: "units" } },
  });
  m = await import(pathToFileURL(join(out, "units.js")).href);
  await rm(out, { recursive: true, force: true });
});

/** A frame as the server writes it (docs/web-protocol.md), with `extra` series beyond the page's. */
function frame(ts, values, { extra = 0, magic = "HPT1", version = 1 } = {}) {
  const N = m.N_SERIES;
  const S = N + extra;
  const B = ts.length;
  const buf = new ArrayBuffer(16 + 8 * B + 8 * B * S);
  const v = new DataView(buf);
  for (let i = 0; i < 4; i++) v.setUint8(i, magic.charCodeAt(i));
  v.setUint16(4, version, true);
  v.setUint16(6, S, true);
  v.setUint32(8, B, true);
  ts.forEach((t, b) => v.setFloat64(16 + 8 * b, t, true));
  let off = 16 + 8 * B;
  for (let b = 0; b < B; b++) {
    for (let s = 0; s < S; s++) {
      const [lo, hi] = s < N ? values(b, s) : [999, 999];
      v.setFloat32(off, lo, true);
      v.setFloat32(off + 4, hi, true);
      off += 8;
    }
  }
  return buf;
}

describe("decodeFrame", () => {
  test("reads times and min/max per series, skipping series the page does not know", () => {
    const f = m.decodeFrame(frame([1.5, 1.501], (b, s) => [b * 10 + s, b * 10 + s + 0.5], { extra: 2 }));
    assert.equal(f.nBuckets, 2);
    assert.deepEqual([...f.t], [1.5, 1.501]);
    const N = m.N_SERIES;
    assert.equal(f.minMax.length, 2 * N * 2);
    assert.equal(f.minMax[2 * 3], 3); // bucket 0, series 3, min
    assert.equal(f.minMax[2 * N + 2 * 6 + 1], 16.5); // bucket 1, series 6, max
    assert.ok(![...f.minMax].includes(999), "extra series dropped");
  });
  test("a frame from a server that sends fewer series reads the page's later ones as NaN", () => {
    const N = m.N_SERIES;
    const S = m.MIN_SERIES;
    const buf = new ArrayBuffer(16 + 8 * 2 + 8 * 2 * S);
    const v = new DataView(buf);
    [0x48, 0x50, 0x54, 0x31].forEach((c, i) => v.setUint8(i, c));
    v.setUint16(4, 1, true);
    v.setUint16(6, S, true);
    v.setUint32(8, 2, true);
    for (let b = 0; b < 2; b++) {
      v.setFloat64(16 + 8 * b, b, true);
      for (let s = 0; s < S; s++) {
        v.setFloat32(32 + (b * S + s) * 8, b * 100 + s, true);
        v.setFloat32(32 + (b * S + s) * 8 + 4, b * 100 + s + 0.5, true);
      }
    }
    const f = m.decodeFrame(buf);
    assert.equal(f.minMax.length, 2 * N * 2);
    assert.equal(f.minMax[2 * N + 2 * (S - 1) + 1], 100 + S - 1 + 0.5); // bucket 1, last sent series, max
    for (let b = 0; b < 2; b++) for (let s = S; s < N; s++) assert.ok(Number.isNaN(f.minMax[b * 2 * N + 2 * s]), `bucket ${b} series ${s} NaN`);
  });
  test("refuses bad frames with a message that says what is wrong", () => {
    const good = frame([0], () => [0, 0]);
    assert.throws(() => m.decodeFrame(frame([0], () => [0, 0], { magic: "HPT2" })), /bad magic/);
    assert.throws(() => m.decodeFrame(frame([0], () => [0, 0], { version: 2 })), /unsupported frame version 2/);
    assert.throws(() => m.decodeFrame(good.slice(0, 10)), /shorter than its header/);
    assert.throws(() => m.decodeFrame(good.slice(0, good.byteLength - 4)), /header says/);
    const few = new ArrayBuffer(16);
    const v = new DataView(few);
    [0x48, 0x50, 0x54, 0x31].forEach((c, i) => v.setUint8(i, c));
    v.setUint16(4, 1, true);
    v.setUint16(6, m.MIN_SERIES - 1, true);
    assert.throws(() => m.decodeFrame(few), new RegExp(`has ${m.MIN_SERIES - 1} series, the page needs at least ${m.MIN_SERIES}`));
  });
});

describe("TelemetryStore", () => {
  const ones = () => Array(m.N_SERIES).fill(1);
  const fill = (store, t0, n, dt, val = (i, s) => [i + s, i + s + 1]) => {
    const ts = Array.from({ length: n }, (_, i) => t0 + i * dt);
    store.append(m.decodeFrame(frame(ts, (b, s) => val(b, s))));
  };

  test("keeps the newest buckets when full, in time order", () => {
    const st = new m.TelemetryStore(8);
    fill(st, 0, 5, 1);
    fill(st, 5, 6, 1);
    assert.equal(st.length, 8);
    assert.equal(st.appended, 11);
    assert.equal(st.firstTime(), 3);
    assert.equal(st.lastTime(), 10);
    assert.deepEqual(Array.from({ length: 8 }, (_, i) => st.timeAt(i)), [3, 4, 5, 6, 7, 8, 9, 10]);
    assert.equal(st.lowerBound(6.5), 4);
    assert.equal(st.lowerBound(-1), 0);
    assert.equal(st.lowerBound(11), 8);
  });

  test("a run whose time starts again replaces the old history", () => {
    const st = new m.TelemetryStore(16);
    fill(st, 100, 5, 1);
    fill(st, 0, 3, 1);
    assert.equal(st.restarts, 1);
    assert.equal(st.length, 3);
    assert.equal(st.firstTime(), 0);
  });

  test("merging into pixel columns keeps a one-bucket spike and the extremes", () => {
    const st = new m.TelemetryStore(1 << 14);
    // 10 000 buckets of 1 ms; series 1 is 1.0 everywhere except a 5.0 spike in bucket 4321
    // and a -2.0 dip in bucket 777.
    fill(st, 0, 10000, 0.001, (i, s) => (s === 1 ? (i === 4321 ? [1, 5] : i === 777 ? [-2, 1] : [1, 1]) : [0, 0]));
    const c = m.readColumns(st, 0, 10, 500, ones());
    assert.ok(c.t.length <= 500 && c.t.length > 450, `${c.t.length} columns`);
    assert.equal(c.bucketsInRange, 10000);
    assert.equal(Math.max(...c.max[1]), 5);
    assert.equal(Math.min(...c.min[1]), -2);
    const spikeCols = c.max[1].filter((v) => v === 5).length;
    assert.equal(spikeCols, 1, "the spike is in exactly one column");
    // Few buckets: drawn as they are, with unit scaling.
    const raw = m.readColumns(st, 1.0, 1.01, 500, ones().map((v, s) => (s === 1 ? 1000 : v)));
    assert.equal(raw.t.length, 11);
    assert.equal(raw.max[1][0], 1000);
  });

  test("a hole in the data becomes a gap (null), not a line across it", () => {
    const st = new m.TelemetryStore(1 << 14);
    fill(st, 0, 3000, 0.001, () => [1, 2]);
    fill(st, 6, 3000, 0.001, () => [1, 2]);
    const c = m.readColumns(st, 0, 9, 300, ones());
    const gaps = c.max[0].filter((v) => v === null).length;
    assert.equal(gaps, 1, "one null marks the 3 s hole");
    const gi = c.max[0].indexOf(null);
    assert.ok(c.t[gi] >= 2.999 && c.t[gi] < 6, `gap at ${c.t[gi]}`);
    assert.ok(c.t[gi - 1] < 3 && c.t[gi + 1] >= 6, "between the last point before the hole and the first after");
  });

  test("NaN series (no model, a real board's F_true) are gaps, not zeros", () => {
    const st = new m.TelemetryStore(64);
    fill(st, 0, 10, 0.001, (i, s) => (s === 2 ? [NaN, NaN] : [i, i]));
    const c = m.readColumns(st, 0, 1, 100, ones());
    assert.ok(c.max[2].every((v) => v === null));
    assert.equal(st.hasFinite(2, 0, 10), false);
    assert.equal(st.hasFinite(1, 0, 10), true);
  });

  test("CSV export: the range at full resolution with min and max of every series", () => {
    const st = new m.TelemetryStore(64);
    fill(st, 0, 20, 0.5, (i, s) => (s === 6 ? [NaN, NaN] : [i * 10 + s, i * 10 + s + 0.25]));
    const csv = m.toCsv(st, 2, 4, m.SERIES).trim().split("\n");
    assert.equal(csv[0], ["t_s", ...m.SERIES.flatMap((n) => [`${n}_min`, `${n}_max`])].join(","));
    assert.equal(csv.length, 1 + 5); // t = 2, 2.5, 3, 3.5, 4
    const want = ["2.000000"];
    for (let s = 0; s < m.N_SERIES; s++) want.push(...(s === 6 ? ["", ""] : [String(40 + s), String(40 + s + 0.25)]));
    assert.equal(csv[1], want.join(","));
  });
});

describe("which model drew each point", () => {
  // Columns as readColumns gives them, only the model_id series filled.
  const cols = (ids) => {
    const s = m.SERIES.indexOf("model_id");
    const c = { t: ids.map((_, i) => i * 0.1), min: m.SERIES.map(() => []), max: m.SERIES.map(() => []), bucketsInRange: ids.length };
    for (const id of ids) {
      c.min[s].push(Array.isArray(id) ? id[0] : id);
      c.max[s].push(Array.isArray(id) ? id[1] : id);
    }
    return [c, s];
  };
  test("runs of one id; a column holding a swap is its own run; a gap ends a run", () => {
    const [c, s] = cols([1, 1, [1, 2], 2, 2, null, 2, 0, 0]);
    const runs = m.modelRuns(c, s, 1.0);
    assert.deepEqual(runs.map((r) => r.id), [1, null, 2, 2, 0]);
    assert.deepEqual(runs.map((r) => [r.t0, r.t1].map((x) => Math.round(x * 10) / 10)), [[0, 0.2], [0.2, 0.3], [0.3, 0.5], [0.6, 0.7], [0.7, 1.0]]);
  });
  test("ids are named from the model list and the status, and keep their name", () => {
    const n = new m.ModelNames();
    n.learn([{ name: "rf6", state: "active", model_id: 3 }, { name: "lstm6", state: "available", model_id: 0 }, null]);
    assert.equal(n.name(3), "rf6");
    assert.equal(n.name(0), "no model");
    assert.equal(n.name(null), "swap");
    assert.equal(n.name(7), "model #7");
    n.learn([{ name: "lstm6", state: "active", model_id: 4 }]);
    assert.deepEqual([n.name(3), n.name(4)], ["rf6", "lstm6"]);
    assert.equal(m.normalizeModel({ name: "x", state: "active", model_id: 5 }).model_id, 5);
  });
});

describe("status and models", () => {
  test("enum words with or without their proto prefix; no model means null", () => {
    assert.equal(m.normalizeState("MODEL_STATE_ACTIVE"), "active");
    assert.equal(m.normalizeState("loaded"), "loaded");
    assert.equal(m.normalizeStatus({ active_model: { name: "" } }).active_model, null);
    assert.equal(m.normalizeStatus({ active_model: null, loop_alive: false }).loop_alive, false);
    assert.equal(m.normalizeStatus({ type: "status", active_model: { name: "rf", state: "MODEL_STATE_ACTIVE" } }).active_model.state, "active");
  });
  test("the server's nested status object becomes the page's figures", () => {
    const st = m.normalizeStatus({
      type: "status",
      server: { version: "0.1.0", uptime_s: 3, token_required: true, predictions: 9, inference_latency_us: { p50: 1, p99: 2, p999: 3, max: 4, count: 5 } },
      loop: {
        alive: true, clock: "realtime", board: "sim", rate_hz: 9999.5, steps: 12345, deadline_misses: 2, fallbacks: 7,
        latency_us: { p50: 6, p99: 14, p999: 31, max: 60, count: 100 },
        experiment: { kind: "abstraction", running: true, cycle: 3, phase: "ramp-up" },
        scheduling: "SCHED_FIFO 80", recorder: "off", telemetry_drops: 0,
        on_time: 12338, late_one: 4, held: 2, fallback: 1, corrupt: 0, max_transition_step_n: 0.04,
      },
      active_model: { name: "rf6", kind: "stateless", features: ["position_x"], since_step: 10, model_id: 2 },
    });
    assert.deepEqual([st.on_time, st.late_one, st.held, st.fallback, st.corrupt], [12338, 4, 2, 1, 0]);
    assert.equal(st.max_transition_step_n, 0.04);
    assert.equal(st.loop_alive, true);
    assert.equal(st.rate_hz, 9999.5);
    assert.equal(st.step, 12345);
    assert.equal(st.deadline_misses, 2);
    assert.equal(st.fallbacks, 7);
    assert.deepEqual(st.round_trip_latency, { p50_us: 6, p99_us: 14, p999_us: 31, max_us: 60, count: 100 });
    assert.equal(st.inference_latency.p99_us, 2);
    assert.equal(st.mode, "abstraction");
    assert.equal(st.experiment_cycle, 3);
    assert.equal(st.active_model.name, "rf6");
    assert.equal(st.server_version, "0.1.0");
    assert.equal(st.token_required, true);
    const idle = m.normalizeStatus({ loop: { alive: false, experiment: { kind: "abstraction", running: false } }, server: {}, active_model: null });
    assert.equal(idle.mode, "idle");
    assert.equal(idle.loop_alive, false);
    assert.equal(idle.active_model, null);
  });

  test("the model list as a plain list or wrapped as gRPC answers it", () => {
    const l = [{ name: "a", state: "available" }, { name: "", state: "x" }, { nope: 1 }];
    assert.deepEqual(m.normalizeModels(l).map((x) => x.name), ["a"]);
    assert.deepEqual(m.normalizeModels({ models: l }).map((x) => x.name), ["a"]);
    assert.deepEqual(m.normalizeModels(null), []);
  });
});
