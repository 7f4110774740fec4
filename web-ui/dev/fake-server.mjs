#!/usr/bin/env node
// A stand-in for infer-server's HTTP side, speaking docs/web-protocol.md with synthetic data from
// a small sponge model (nonlinear stiffness, a viscoelastic branch that makes loading and
// unloading differ, unilateral contact, encoder quantisation, noise and occasional one-step
// force spikes), stepped at 10 kHz under a force command that follows ramp cycles.
//
// It exists for developing the page and for the page-only test (tests/page.fake.test.mjs); the
// real test (tests/system.test.mjs) runs against target/release/infer-server and rt-loop. Its
// names (the series and their order, the phases, the features its models use) are the
// generated vocabulary's (src/vocab.ts, from proto/, loaded through Vite), never copies of its
// own; tests/fake-schema.test.mjs checks its JSON and frames against the real control plane.
//
//   node dev/fake-server.mjs [--port 8080] [--token T] [--bucket 10] [--rate 10000] [--demo]
//
// Also usable from a test: `const s = await startFakeServer({ port: 0 })`.
import { createServer } from "node:http";
import { readFile } from "node:fs/promises";
import { extname, join, normalize, dirname } from "node:path";
import { fileURLToPath } from "node:url";
import { runnerImport } from "vite";
import { WebSocketServer } from "ws";

const here = dirname(fileURLToPath(import.meta.url));
const { module: vocab } = await runnerImport(join(here, "..", "src", "vocab.ts"));
/** The telemetry series in the server's order. */
export const SERIES = vocab.SERIES;
/** Where each quantity the bench computes goes in a telemetry row; a series it cannot fill is an error. */
const FIELDS = ["F_ref", "rtob_force", "F_pred", "position_x", "velocity", "acceleration", "F_true", "f_previous", "model_id", "F_object"];
const unknown = SERIES.filter((n) => !FIELDS.includes(n));
if (unknown.length) throw new Error(`fake-server: the vocabulary has series it does not fill: ${unknown.join(", ")}`);
const COLUMN = FIELDS.map((n) => SERIES.indexOf(n));
/** The loop's phases as the status's `loop.experiment.phase` names them (by their column value). */
const [HOLD_ZERO, RAMP_UP, HOLD_MAX, RAMP_DOWN, , REPRODUCTION, DONE] = vocab.PHASE_NAMES;

/** Deterministic noise (the same seed gives the same run), xorshift32 + Box-Muller. */
function rng(seed) {
  let s = seed >>> 0 || 1;
  const u = () => {
    s ^= s << 13;
    s >>>= 0;
    s ^= s >>> 17;
    s ^= s << 5;
    s >>>= 0;
    return (s + 0.5) / 4294967296;
  };
  return { u, n: () => Math.sqrt(-2 * Math.log(u())) * Math.cos(2 * Math.PI * u()) };
}

/** The synthetic bench: sponge + force control + observers' look, one step at a time. */
export class FakeBench {
  constructor(rateHz = 10000, seed = 7) {
    this.rate = rateHz;
    this.dt = 1 / rateHz;
    this.r = rng(seed);
    this.reset();
  }

  reset() {
    this.step = 0;
    this.t = 0;
    this.F = 0; // contact force the probe applies (true)
    this.x = 0; // true depth, m
    this.s = 0; // viscoelastic (Maxwell) branch force
    this.perm = 0; // permanent deformation, m
    this.vInt = 0;
    this.v = 0;
    this.aInt = 0;
    this.a = 0;
    this.prevF = 0; // the previous step's RFOB force: the f_previous feature
    this.fric = 0; // the guide's friction, N (felt, not the object's)
    this.row = new Float64Array(SERIES.length);
    this.exp = { kind: "idle", running: false };
    this.phase = DONE;
  }

  /** Ramp cycles: hold 0, ramp up to F_max, hold, ramp down, hold 0; F_max grows per cycle. */
  startExperiment(req) {
    this.exp = {
      kind: req.kind,
      running: true,
      t0: this.t,
      rate: req.ramp_rate ?? 6.2,
      cycles: req.cycles ?? 3,
      fMax0: req.f_max_start ?? 4,
      fStep: req.f_max_step ?? 1,
    };
  }

  stopExperiment() {
    this.exp = { kind: "idle", running: false };
  }

  command() {
    const e = this.exp;
    if (!e.running) {
      this.phase = DONE;
      return 0.3;
    }
    const tt = this.t - e.t0;
    if (e.kind === "reproduction") {
      // A hand pressing and releasing every 4 s; the command is what the model renders.
      this.phase = REPRODUCTION;
      return 5 * (1 - Math.cos((2 * Math.PI * tt) / 4)) / 2 + 0.3;
    }
    const hold = 0.5;
    let t0 = 0;
    for (let c = 0; c < e.cycles; c++) {
      const fMax = Math.min(14, e.fMax0 + c * e.fStep);
      const ramp = fMax / e.rate;
      const len = hold + ramp + hold + ramp + hold;
      if (tt < t0 + len) {
        const u = tt - t0;
        this.cycle = c + 1;
        if (u < hold) return (this.phase = HOLD_ZERO), 0.3;
        if (u < hold + ramp) return (this.phase = RAMP_UP), 0.3 + (u - hold) * e.rate;
        if (u < 2 * hold + ramp) return (this.phase = HOLD_MAX), 0.3 + fMax;
        if (u < 2 * hold + 2 * ramp) return (this.phase = RAMP_DOWN), 0.3 + fMax - (u - 2 * hold - ramp) * e.rate;
        return (this.phase = HOLD_ZERO), 0.3;
      }
      t0 += len;
    }
    this.exp = { kind: "idle", running: false };
    return 0.3;
  }

  /**
   * One 10 kHz step with `model` (and the id its answers carry; 0 without one); returns the
   * telemetry row, every series in the page's order (SI units). The row is reused.
   */
  advance(model, modelId = 0) {
    const dt = this.dt;
    const Fcmd = this.command();
    // Force control with ~300 rad/s bandwidth; the probe cannot pull the sponge.
    this.F += 300 * (Fcmd - this.F) * dt;
    const k1 = 220;
    const k3 = 3.5e5;
    const k2 = 260;
    const tau = 0.6;
    const c = 90;
    const xe = Math.max(0, this.x - this.perm);
    const fel = k1 * xe + k3 * xe * xe * xe;
    let xdot = (this.F - fel - this.s) / c;
    if (this.x <= 0 && xdot < 0) xdot = 0;
    this.x = Math.max(0, this.x + xdot * dt);
    this.s += (k2 * xdot - this.s / tau) * dt;
    // Permanent deformation grows with the largest depth, recovers a little.
    this.perm = Math.max(this.perm, 0.04 * xe) * (1 - 0.02 * dt);
    // The object's own force, and the felt force: the object's plus the friction of the
    // probe's guide (as the simulated bench's F_true carries it on a hand run), a Dahl element
    // of 20 um that keeps its last value when the probe stops (a hold is never friction-free).
    const Fobject = fel + this.s + c * xdot;
    this.fric = Math.max(-0.09, Math.min(0.09, this.fric + (0.09 * xdot * dt) / 2e-5));
    const Ftrue = Fobject + this.fric;
    // Encoder: 5 um counts; pseudo-derivatives as the loop computes them.
    const xq = Math.round(this.x / 5e-6) * 5e-6;
    this.vInt += this.v * dt;
    this.v = 30 * (xq - this.vInt);
    this.aInt += this.a * dt;
    this.a = 100 * (this.v - this.aInt);
    let Fres = Ftrue + 0.03 * this.r.n();
    if (this.step % 25000 === 12345) Fres += 2.5; // a one-step spike every 2.5 s (what min/max buckets must keep)
    let Fpred = NaN;
    if (model) Fpred = model.predict(xq, this.v, Fobject, this.r);
    this.t += dt;
    this.step++;
    const values = [Fcmd, Fres, Fpred, xq, this.v, this.a, Ftrue, this.prevF, model ? modelId : 0, Fobject];
    for (let k = 0; k < values.length; k++) this.row[COLUMN[k]] = values[k];
    this.prevF = Fres;
    return this.row;
  }
}

/** Three "models" whose errors differ visibly (a spring-damper fit has no hysteresis at all). */
/** The first six features of thesis Table 3.1 (kinematics and the three f_previous ratios). */
const SIX = vocab.THESIS_FEATURES.slice(0, 6);
const MODELS = {
  rf6: { kind: "stateless", features: SIX, predict: (_x, _v, F, r) => F * 1.01 + 0.06 * r.n() },
  // carries reference steps (`haptics.reference`), which the server reports checked once loaded
  lstm6: { kind: "stateful", features: SIX, referenceSteps: 32, predict: (_x, _v, F, r) => 0.93 * F + 0.15 + 0.08 * r.n() },
  spring_damper2: {
    kind: "stateless",
    features: SIX.slice(0, 2),
    predict: (x, v) => Math.max(0, 180 * x + 9000 * x * x + 40 * v),
    // As infer-server says of a model fitted on features of other filters than the loop's.
    warnings: ["its training features were computed with other filters (haptics.feature_gains): velocity at g_v 10.0 rad/s (the loop's 30.0)"],
  },
};

const MIME = { ".html": "text/html; charset=utf-8", ".js": "text/javascript", ".css": "text/css", ".svg": "image/svg+xml", ".png": "image/png", ".json": "application/json" };

function percentile(sorted, q) {
  return sorted.length ? sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))] : 0;
}

export async function startFakeServer(opts = {}) {
  const rate = opts.rate ?? 10000;
  const bucket = opts.bucket ?? 10;
  const token = opts.token ?? null;
  const dist = opts.dist ?? join(here, "..", "dist");
  const bench = new FakeBench(rate, opts.seed ?? 7);
  const state = {
    loopAlive: true,
    models: Object.fromEntries(Object.keys(MODELS).map((n) => [n, n === "rf6" ? "active" : "available"])),
    active: "rf6",
    /** The id each model's answers carry: its generation, given when it is activated (0: never). */
    modelIds: Object.fromEntries(Object.keys(MODELS).map((n) => [n, n === "rf6" ? 1 : 0])),
    generation: 1,
    activeSince: 0,
    fallbacks: 0,
    misses: 0,
    startedAt: Date.now(),
    simStart: performance.now(),
    predictions: 0,
    requests: [],
  };
  if (opts.demo) bench.startExperiment({ kind: "abstraction", ramp_rate: 3.9, cycles: 1000, f_max_start: 3, f_max_step: 1 });

  // Simulated steps advance with the wall clock; the buckets produced since the last tick are
  // sent on each tick to every socket (each socket sees the same data).
  const pending = []; // [{t, mm: Float32Array(14)}]
  let acc = null;
  let accN = 0;
  function simulateTo(now) {
    if (!state.loopAlive) return;
    const target = Math.floor(((now - state.simStart) / 1000) * rate);
    const model = state.active ? MODELS[state.active] : null;
    let n = 0;
    while (bench.step < target && n < rate) {
      const t = bench.t;
      const v = bench.advance(model, model ? state.modelIds[state.active] : 0);
      if (model) state.predictions++;
      if (bench.r.u() < 1 / 200000) state.fallbacks++;
      if (!acc) {
        acc = { t, mm: new Float32Array(SERIES.length * 2) };
        for (let s = 0; s < SERIES.length; s++) {
          acc.mm[2 * s] = v[s];
          acc.mm[2 * s + 1] = v[s];
        }
      } else {
        for (let s = 0; s < SERIES.length; s++) {
          if (v[s] < acc.mm[2 * s]) acc.mm[2 * s] = v[s];
          if (v[s] > acc.mm[2 * s + 1]) acc.mm[2 * s + 1] = v[s];
        }
      }
      if (++accN === bucket) {
        pending.push(acc);
        acc = null;
        accN = 0;
      }
      n++;
    }
  }

  function frame(buckets) {
    const S = SERIES.length;
    const B = buckets.length;
    const buf = Buffer.alloc(16 + 8 * B + 8 * B * S);
    buf.write("HPT1", 0, "latin1");
    buf.writeUInt16LE(1, 4);
    buf.writeUInt16LE(S, 6);
    buf.writeUInt32LE(B, 8);
    buf.writeUInt32LE(0, 12);
    let off = 16;
    for (const b of buckets) {
      buf.writeDoubleLE(b.t, off);
      off += 8;
    }
    for (const b of buckets) {
      for (let k = 0; k < 2 * S; k++) {
        buf.writeFloatLE(b.mm[k], off);
        off += 4;
      }
    }
    return buf;
  }

  /** The status object in the shape infer-server's control plane sends (docs/web-protocol.md). */
  function status() {
    const lat = [];
    for (let i = 0; i < 64; i++) lat.push(5 + Math.abs(bench.r.n()) * 2 + (bench.r.u() < 0.02 ? 20 * bench.r.u() : 0));
    lat.sort((a, b) => a - b);
    const pct = (k) => ({ p50: percentile(lat, 0.5) * k, p99: percentile(lat, 0.99) * k, p999: lat[lat.length - 1] * k, max: lat[lat.length - 1] * k * 1.2, count: state.predictions });
    const m = state.active ? MODELS[state.active] : null;
    return {
      server: {
        version: "fake-0.1",
        uptime_s: (Date.now() - state.startedAt) / 1000,
        token_required: !!token,
        max_upload_bytes: 64 << 20,
        predictions: state.predictions,
        inference_latency_us: pct(0.6),
      },
      loop: {
        alive: state.loopAlive,
        clock: "realtime",
        board: "fake",
        rate_hz: state.loopAlive ? rate * (1 + 0.0002 * bench.r.n()) : 0,
        steps: bench.step,
        deadline_misses: state.misses,
        overruns: 0,
        period_jitter_us: pct(0.1),
        fallbacks: state.fallbacks,
        // the fake bench has no ladder: a step is on time or rendered by the fallback
        on_time: Math.max(0, bench.step - state.fallbacks),
        late_one: 0,
        held: 0,
        fallback: state.fallbacks,
        corrupt: 0,
        max_transition_step_n: 0,
        latency_us: pct(1),
        experiment: { kind: bench.exp.running ? bench.exp.kind : "idle", running: !!bench.exp.running, cycle: bench.exp.running ? bench.cycle ?? 0 : 0, phase: bench.phase },
        scheduling: "SCHED_OTHER (fake)",
        recorder: "off",
        recorder_failed: false,
        telemetry_drops: 0,
        // the fake bench never saturates, has no real board and no passivity layer acting
        saturated: 0,
        board_faults: 0,
        board_fault: "",
        board_fifo_overflows: 0,
        board_quadrature_errors: 0,
        passivity: { on: false, energy_j: 0, received_j: 0, returned_j: 0, damping_ns_per_m: 0, active_steps: 0 },
      },
      active_model: m ? { name: state.active, kind: m.kind, features: m.features, since_step: state.activeSince, model_id: state.modelIds[state.active] } : null,
    };
  }

  /** A model as /api/models lists it (control-plane's ModelJson). */
  const modelJson = (n) => ({
    name: n,
    state: state.models[n],
    kind: MODELS[n].kind,
    features: MODELS[n].features,
    units: "N",
    size_bytes: 1000,
    model_id: state.modelIds[n],
    ...(n === state.active ? { active_since_step: state.activeSince } : {}),
    provenance: null,
    cost: null,
    reference_steps: ["loaded", "active"].includes(state.models[n]) ? (MODELS[n].referenceSteps ?? 0) : 0,
  });
  const json = (res, code, body) => {
    res.writeHead(code, { "Content-Type": "application/json", "Cache-Control": "no-store" });
    res.end(JSON.stringify(body));
  };
  const authorized = (req) => !token || req.headers.authorization === `Bearer ${token}`;
  const readBody = (req) =>
    new Promise((resolve) => {
      let d = "";
      req.on("data", (c) => (d += c));
      req.on("end", () => resolve(d));
    });

  const server = createServer(async (req, res) => {
    const url = new URL(req.url, "http://x");
    const p = url.pathname;
    state.requests.push(`${req.method} ${p}`);
    if (p.startsWith("/api/")) {
      if (req.method === "POST" && !p.startsWith("/api/_fake") && !authorized(req)) return json(res, 401, { error: "missing or wrong token" });
      if (req.method === "GET" && p === "/api/status") return json(res, 200, status());
      if (req.method === "GET" && p === "/api/models") return json(res, 200, Object.keys(MODELS).map(modelJson));
      const mm = p.match(/^\/api\/models\/([^/]+)\/(load|activate)$/);
      if (req.method === "POST" && mm) {
        const name = decodeURIComponent(mm[1]);
        if (!MODELS[name]) return json(res, 400, { error: `no model named ${name}` });
        if (mm[2] === "load") {
          if (state.models[name] === "available") state.models[name] = "loaded";
          return json(res, 200, modelJson(name));
        }
        // As infer-server: an available model is loaded first unless ?load_if_needed=false.
        if (state.models[name] === "available" && url.searchParams.get("load_if_needed") === "false") return json(res, 412, { error: `${name} is not loaded` });
        if (state.active) state.models[state.active] = "loaded";
        state.active = name;
        state.models[name] = "active";
        state.modelIds[name] = ++state.generation;
        state.activeSince = bench.step + 1;
        return json(res, 200, { effective_step: state.activeSince, model: modelJson(name), warnings: MODELS[name].warnings ?? [] });
      }
      if (req.method === "POST" && p === "/api/experiment/start") {
        let body;
        try {
          body = JSON.parse((await readBody(req)) || "{}");
        } catch {
          return json(res, 400, { error: "body is not JSON" });
        }
        if (!["abstraction", "reproduction", "shadow"].includes(body.kind)) return json(res, 400, { error: `unknown experiment kind ${body.kind}` });
        if (!state.loopAlive) return json(res, 412, { error: "no loop attached" });
        bench.startExperiment(body);
        return json(res, 200, {});
      }
      if (req.method === "POST" && p === "/api/experiment/stop") {
        bench.stopExperiment();
        return json(res, 200, {});
      }
      if (req.method === "POST" && p === "/api/_fake/loop") {
        // Development only: make the loop vanish (or come back as a new run, time from 0).
        const body = JSON.parse((await readBody(req)) || "{}");
        setLoopAlive(!!body.alive);
        return json(res, 200, {});
      }
      return json(res, 404, { error: `no such endpoint ${req.method} ${p}` });
    }
    if (p === "/metrics") {
      res.writeHead(200, { "Content-Type": "text/plain; version=0.0.4" });
      return res.end(`# TYPE haptics_loop_steps counter\nhaptics_loop_steps ${bench.step}\n`);
    }
    if (req.method !== "GET") return json(res, 405, { error: "method not allowed" });
    const rel = p === "/" ? "index.html" : normalize(decodeURIComponent(p)).replace(/^([/\\])+/, "");
    if (rel.startsWith("..")) return json(res, 400, { error: "bad path" });
    try {
      const body = await readFile(join(dist, rel));
      res.writeHead(200, { "Content-Type": MIME[extname(rel)] ?? "application/octet-stream" });
      res.end(body);
    } catch {
      json(res, 404, { error: `not found: ${p}` });
    }
  });

  const wss = new WebSocketServer({ noServer: true });
  server.on("upgrade", (req, socket, head) => {
    const url = new URL(req.url, "http://x");
    if (url.pathname !== "/ws/telemetry") return socket.destroy();
    wss.handleUpgrade(req, socket, head, (ws) => {
      const fps = Math.max(1, Math.min(60, Number(url.searchParams.get("fps")) || 30));
      ws.fps = fps;
      ws.send(JSON.stringify({ type: "status", ...status() }));
    });
  });

  const fpsMax = 60;
  let lastStatus = 0;
  const tick = setInterval(() => {
    const now = performance.now();
    simulateTo(now);
    const buckets = pending.splice(0, pending.length);
    const bin = buckets.length ? frame(buckets) : null;
    const sendStatus = now - lastStatus > 500;
    if (sendStatus) lastStatus = now;
    const st = sendStatus ? JSON.stringify({ type: "status", ...status() }) : null;
    for (const ws of wss.clients) {
      if (ws.readyState !== 1) continue;
      if (bin) ws.send(bin);
      if (st) ws.send(st);
    }
  }, 1000 / fpsMax);

  function setLoopAlive(alive) {
    if (alive && !state.loopAlive) {
      bench.reset();
      state.simStart = performance.now();
      acc = null;
      accN = 0;
    }
    state.loopAlive = alive;
  }

  await new Promise((resolve) => server.listen(opts.port ?? 8080, opts.host ?? "127.0.0.1", resolve));
  const port = server.address().port;
  return {
    port,
    url: `http://127.0.0.1:${port}`,
    state,
    bench,
    setLoopAlive,
    /** Sends raw bytes or text to every page (tests use it to send a malformed frame). */
    broadcast(data) {
      for (const ws of wss.clients) if (ws.readyState === 1) ws.send(data);
    },
    async close() {
      clearInterval(tick);
      for (const ws of wss.clients) ws.terminate();
      wss.close();
      server.closeAllConnections?.();
      await new Promise((r) => server.close(r));
    },
  };
}

if (process.argv[1] && fileURLToPath(import.meta.url) === normalize(process.argv[1])) {
  const a = process.argv.slice(2);
  const arg = (k, d) => {
    const i = a.indexOf(k);
    return i >= 0 ? a[i + 1] : d;
  };
  const s = await startFakeServer({
    port: Number(arg("--port", 8080)),
    token: arg("--token", process.env.HAPTICS_TOKEN ?? null),
    bucket: Number(arg("--bucket", 10)),
    rate: Number(arg("--rate", 10000)),
    demo: a.includes("--demo"),
  });
  console.log(`fake infer-server (web side only) listening on ${s.url}`);
}
