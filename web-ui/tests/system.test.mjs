// SYSTEM test: the page in real headless Chromium against the REAL processes, started here from
// target/release (or $HAPTICS_BIN_DIR): rt-loop on the simulated sponge bench at 10 kHz, and
// infer-server serving the page (embedded from web-ui/dist), the WebSocket and /api/*.
//
// Nothing here passes by not running: a missing binary FAILS under CI=true and is an explicit,
// counted skip elsewhere (node:test's "# skipped" count, which scripts/test.sh sums); a binary
// that is there but cannot start, a flag it does not know, or a server that does not answer
// FAIL everywhere.
//
// Command lines (placeholders {http} {grpc} {models} {instance} {bin} {tmp} are filled in;
// whitespace-split; {instance} is unique to this run so a developer's own loop is not touched):
//   HAPTICS_RT_LOOP_ARGS        default: RT_LOOP_SERVE below
//   HAPTICS_INFER_SERVER_ARGS   default: INFER_SERVER_SERVE below
//   HAPTICS_HAPTICCTL_ARGS      default: --addr http://{grpc} --json status
//   HAPTICS_MODELS_DIR          default: fixture models written by
//                               infer-server/tests/fixtures/make_models.py with .venv's python,
//                               or else ./models
import { after, before, describe, test } from "node:test";
import assert from "node:assert/strict";
import { spawn, spawnSync } from "node:child_process";
import { existsSync } from "node:fs";
import { mkdir, mkdtemp, rm } from "node:fs/promises";
import { cpus, loadavg, tmpdir } from "node:os";
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import { enclosedArea, finite, freePort, frozenDrawn, hook, measureFrames, missing, openBrowser, skipMissing, sleep, vocab, waitFor } from "./harness.mjs";

// How the processes are started: the one place to change when their command lines change.
// Every flag is passed: a flag the program does not know fails the run (it is not left out).
// Both sides wait spin-then-park: this machine may have two cores, and a test must not busy-spin
// on both sides of the ring.
const RT_LOOP_SERVE = "serve --clock realtime --rate-hz 10000 --board sim --instance {instance} --wait spin-park";
const INFER_SERVER_SERVE = "serve --models {models} --instance {instance} --grpc {grpc} --http {http} --wait spin-park";
const DEFAULT_HAPTICCTL_ARGS = "--addr http://{grpc} --json status";

const here = dirname(fileURLToPath(import.meta.url));
const repo = resolve(here, "..", "..");
const binDir = process.env.HAPTICS_BIN_DIR ? resolve(process.env.HAPTICS_BIN_DIR) : join(repo, "target", "release");
const bin = (name) => join(binDir, name);

let shouted = false;
function loudSkip(t, why) {
  skipMissing(t, why); // throws under CI=true: the test fails
  if (shouted) return;
  shouted = true;
  const bar = "!".repeat(100);
  console.log(`${bar}\n!! SYSTEM BROWSER TEST SKIPPED (counted): ${why}\n${bar}`);
}

/** `NAME serve --help` must work: the binary is there, so a failure here is a failure. */
function checkServe(name) {
  const r = spawnSync(bin(name), ["serve", "--help"], { encoding: "utf8", timeout: 10000 });
  if (r.status !== 0) throw new Error(`${bin(name)} serve --help failed (${r.status}): ${(r.stderr || r.stdout || "").trim().split("\n")[0]}`);
}

function fill(args, vars) {
  return args
    .trim()
    .split(/\s+/)
    .filter(Boolean)
    .map((a) => a.replace(/\{(\w+)\}/g, (_, k) => (k in vars ? vars[k] : `{${k}}`)));
}

/** A child process whose output is kept (the last 20 kB) for the failure message. */
function start(name, file, args, env = {}) {
  const child = spawn(file, args, { cwd: repo, env: { ...process.env, ...env }, stdio: ["ignore", "pipe", "pipe"] });
  const p = { name, child, out: "", exited: null };
  const keep = (d) => {
    p.out = (p.out + d.toString()).slice(-20000);
  };
  child.stdout.on("data", keep);
  child.stderr.on("data", keep);
  child.on("exit", (code, sig) => (p.exited = { code, sig }));
  child.on("error", (e) => {
    p.exited = { code: -1, sig: null };
    keep(String(e));
  });
  return p;
}

async function stop(p) {
  if (!p || p.exited) return;
  p.child.kill("SIGINT");
  const end = Date.now() + 5000;
  while (!p.exited && Date.now() < end) await sleep(50);
  if (!p.exited) p.child.kill("SIGKILL");
  while (!p.exited) await sleep(20);
}

function modelsDir(tmp) {
  if (process.env.HAPTICS_MODELS_DIR) return resolve(process.env.HAPTICS_MODELS_DIR);
  const py = join(repo, ".venv", "bin", "python");
  const script = join(repo, "infer-server", "tests", "fixtures", "make_models.py");
  if (existsSync(py) && existsSync(script)) {
    const dir = join(tmp, "models");
    const r = spawnSync(py, [script, dir], { cwd: repo, encoding: "utf8" });
    if (r.status === 0) return dir;
    console.log(`make_models.py failed (${r.status}): ${r.stderr}`);
  }
  return join(repo, "models");
}

/** The connection file infer-server writes once it listens (docs/control-plane.md): the token. */
let connection = null;
async function readConnection(dir, instance) {
  const { readFile } = await import("node:fs/promises");
  connection = JSON.parse(await readFile(join(dir, "haptics", `${instance}.json`), "utf8"));
  return connection;
}

async function getJson(url) {
  // The server requires its token on every read too; the owner's tools take it from the file.
  const headers = connection?.token ? { Authorization: `Bearer ${connection.token}` } : {};
  const r = await fetch(url, { headers, signal: AbortSignal.timeout(2000) });
  if (!r.ok) throw new Error(`${url}: ${r.status}`);
  return r.json();
}

describe("page against the real rt-loop and infer-server", () => {
  const ctx = {};
  let skipWhy = null;

  before(async () => {
    for (const b of ["infer-server", "rt-loop"]) {
      if (!existsSync(bin(b))) {
        skipWhy = missing(`${bin(b)} not found (cargo build --release -p infer-server -p rt-loop, or set HAPTICS_BIN_DIR)`);
        return;
      }
      checkServe(b);
    }
    ctx.tmp = await mkdtemp(join(tmpdir(), "haptics-system-"));
    ctx.http = await freePort();
    ctx.grpc = await freePort();
    ctx.models = modelsDir(ctx.tmp);
    const vars = { http: `127.0.0.1:${ctx.http}`, grpc: `127.0.0.1:${ctx.grpc}`, models: ctx.models, bin: binDir, tmp: ctx.tmp, instance: `webtest-${process.pid}` };
    ctx.vars = vars;
    ctx.rtArgs = fill(process.env.HAPTICS_RT_LOOP_ARGS ?? RT_LOOP_SERVE, vars);
    ctx.loop = start("rt-loop", bin("rt-loop"), ctx.rtArgs);
    await sleep(500);
    ctx.serverArgs = fill(process.env.HAPTICS_INFER_SERVER_ARGS ?? INFER_SERVER_SERVE, vars);
    console.log(`system test: ${bin("rt-loop")} ${ctx.rtArgs.join(" ")}\nsystem test: ${bin("infer-server")} ${ctx.serverArgs.join(" ")}`);
    // The default set-up: no token given, infer-server makes one and writes it, with the page's
    // address, into its connection file (here under a runtime directory of this test's own).
    ctx.env = { XDG_RUNTIME_DIR: ctx.tmp, HAPTICS_TOKEN: "" };
    ctx.server = start("infer-server", bin("infer-server"), ctx.serverArgs, ctx.env);
    ctx.url = `http://127.0.0.1:${ctx.http}`;
    try {
      await waitFor(
        async () => {
          if (ctx.server.exited) return "exited";
          try {
            await readConnection(ctx.tmp, vars.instance);
            return (await getJson(`${ctx.url}/api/status`)) && "ok";
          } catch {
            return false;
          }
        },
        { timeoutMs: 20000, what: "infer-server answering /api/status" },
      ).then((v) => {
        if (v === "exited") throw new Error(`infer-server exited (${JSON.stringify(ctx.server.exited)})`);
      });
    } catch (e) {
      throw new Error(`infer-server does not serve ${ctx.url}/api/status: ${e.message}\n--- infer-server output:\n${ctx.server.out.slice(-3000)}\n--- rt-loop output:\n${ctx.loop.out.slice(-2000)}`);
    }
    ctx.b = await openBrowser({ width: 1440, height: 1080 });
    ctx.page = ctx.b.page;
    // The page's address as infer-server (and scripts/up.sh) print it: `#token=...`.
    assert.match(connection.page, /^http:\/\/127\.0\.0\.1:\d+\/#token=[0-9a-f]{32}$/);
    await ctx.page.goto(connection.page);
    // rt-loop serve idles at 0 A (no steps, no telemetry) until an experiment starts: wait for
    // the status here, and start the ramp cycles from the page in the first test.
    await waitFor(async () => (await hook.status(ctx.page)).loop_alive === true, { timeoutMs: 15000, what: "the page sees the loop attached" });
  });

  after(async () => {
    await ctx.b?.close();
    await stop(ctx.server);
    await stop(ctx.loop);
    if (ctx.tmp) await rm(ctx.tmp, { recursive: true, force: true });
  });

  const it = (name, fn) =>
    test(name, async (t) => {
      if (skipWhy) return loudSkip(t, skipWhy);
      await fn(t);
    });

  it("the page and its assets come from infer-server, and nothing from elsewhere", async () => {
    const origin = new URL(ctx.url).host;
    const foreign = ctx.b.requests.filter((u) => !u.startsWith("data:") && !u.startsWith("blob:") && new URL(u).host !== origin);
    assert.deepEqual(foreign, []);
    assert.deepEqual(ctx.b.consoleErrors, []);
  });

  /** Fills the experiment form and presses Start (Stop first, as the loop refuses a second run). */
  async function startRamps(page, cycles) {
    await page.click("#exp-stop");
    await page.selectOption("#exp-kind", "abstraction");
    await page.fill("#exp-rate", "6.2");
    await page.fill("#exp-cycles", String(cycles));
    await page.fill("#exp-fmax", "5");
    await page.fill("#exp-fstep", "1");
    await page.click("#exp-start");
    await waitFor(async () => (await hook.status(page)).mode === "abstraction", { timeoutMs: 5000, what: "status mode abstraction" });
  }

  it("ramp cycles started from the page: the plots fill and move, and force-depth shows a loop", async () => {
    const page = ctx.page;
    await page.selectOption("#xy-window", "10");
    // Enough cycles to keep the loop running through the following tests (about 4-7 s each).
    await startRamps(page, 8);
    await waitFor(async () => (await hook.points(page, "rtob_force")).t.length > 20, { timeoutMs: 10000, what: "first telemetry on the page" });
    const a = await hook.points(page, "rtob_force");
    const ca = await hook.counts(page);
    await sleep(1500);
    const b = await hook.points(page, "rtob_force");
    const cb = await hook.counts(page);
    assert.ok(cb.buckets > ca.buckets, `buckets arrived: ${ca.buckets} -> ${cb.buckets}`);
    assert.ok(b.t.at(-1) > a.t.at(-1) + 1.0, `device time moved: ${a.t.at(-1)} -> ${b.t.at(-1)}`);
    // Every series of the vocabulary but the prediction (abstraction does not ask the model).
    for (const name of vocab.SERIES.filter((n) => n !== "F_pred")) {
      assert.ok(finite((await hook.points(page, name)).max).length > 5, `${name} reaches the page`);
    }
    const st = await hook.status(page);
    assert.equal(st.loop_alive, true);
    assert.ok(st.rate_hz > 1000, `loop rate shown: ${st.rate_hz}`);
    // Measure when cycle 1 is complete and the probe is back at 0 N (early in cycle 2's hold at
    // zero), so the path is one closed loop plus its start. rt-loop's cycle: hold 0 N (1.5 s),
    // ramp up to 5 N at 6.2 N/s, hold (1 s), ramp down: about 4.1 s.
    await waitFor(async () => (await hook.status(page)).experiment_cycle >= 2, { timeoutMs: 15000, what: "cycle 2 reached" });
    await sleep(400);
    const xy = await hook.xy(page);
    const xr = Math.max(...xy.x) - Math.min(...xy.x);
    const yr = Math.max(...xy.y) - Math.min(...xy.y);
    const area = Math.abs(enclosedArea(xy.x, xy.y));
    console.log(`real force-depth loop: depth ${xr.toFixed(2)} mm, force ${yr.toFixed(2)} N, enclosed ${area.toFixed(2)} N·mm (${((100 * area) / (xr * yr)).toFixed(1)} % of its box)`);
    assert.ok(yr > 3, `force swept the ramp: ${yr} N`);
    assert.ok(xr > 1, `the sponge was compressed: ${xr} mm`);
    // rt-loop's sponge encloses 30-50 % of the box (docs/figures/train_1.8-force-depth.png); a
    // path without hysteresis (up and back the same way, plus noise and spikes) stays under 5 %.
    assert.ok(area > 0.1 * xr * yr, `hysteresis loop encloses ${area} N·mm of ${xr * yr}`);
  });

  it("swapping the model from the page changes the active model (also for hapticctl)", async () => {
    const page = ctx.page;
    const models = await getJson(`${ctx.url}/api/models`);
    const list = Array.isArray(models) ? models : models.models;
    const st0 = await getJson(`${ctx.url}/api/status`);
    const before = st0.active_model?.name ?? "";
    const target = list.find((m) => m.name !== before && !/failed/i.test(String(m.state)) && !m.error && /^(linear|tree)(\.onnx)?$/.test(m.name)) ?? list.find((m) => m.name !== before && !/failed/i.test(String(m.state)) && !m.error);
    assert.ok(target, `a model to swap to in ${ctx.models}: ${JSON.stringify(list.map((m) => m.name))}`);
    await page.click("#models-refresh");
    await page.click(`tr[data-model="${target.name}"] button`);
    await waitFor(async () => (await getJson(`${ctx.url}/api/status`)).active_model?.name === target.name, { timeoutMs: 10000, what: `${target.name} active on the server` });
    await waitFor(async () => (await page.textContent("#f-model")).startsWith(target.name), { what: "figures show the new model" });
    if (existsSync(bin("hapticctl"))) {
      const args = fill(process.env.HAPTICS_HAPTICCTL_ARGS ?? DEFAULT_HAPTICCTL_ARGS, ctx.vars);
      // The owner's hapticctl finds the token in the connection file: none given here.
      const env = { ...process.env, ...ctx.env, HAPTICS_INSTANCE: ctx.vars.instance };
      delete env.HAPTICS_TOKEN;
      const r = spawnSync(bin("hapticctl"), args, { encoding: "utf8", timeout: 10000, env });
      assert.equal(r.status, 0, `hapticctl ${args.join(" ")}: ${r.stderr}`);
      let reported;
      try {
        reported = JSON.parse(r.stdout).active_model?.name;
      } catch {
        // Text output: "model:       NAME (kind, since step N)".
        reported = r.stdout.match(/^model:\s+(\S+)/m)?.[1];
      }
      assert.equal(reported, target.name, `hapticctl status names the model chosen on the page:\n${r.stdout}`);
    } else {
      console.log(`(hapticctl not built at ${bin("hapticctl")}: checked /api/status only)`);
    }
    // A model carrying reference steps (the fixtures' linear_reference: 8), activated from the
    // page: the real server checked them when it loaded it, and the page marks it so.
    const withRef = list.find((m) => /^linear_reference(\.onnx)?$/.test(m.name));
    if (!withRef) {
      // the default models are the fixtures, which have it: missing only with HAPTICS_MODELS_DIR
      assert.ok(process.env.CI !== "true", `no linear_reference model in ${ctx.models} (CI=true)`);
      console.log(`(no linear_reference model in ${ctx.models}: the reference mark not checked)`);
      return;
    }
    await page.click(`tr[data-model="${withRef.name}"] button`);
    await waitFor(async () => (await getJson(`${ctx.url}/api/status`)).active_model?.name === withRef.name, { timeoutMs: 10000, what: `${withRef.name} active on the server` });
    const listed = await getJson(`${ctx.url}/api/models`);
    assert.equal((Array.isArray(listed) ? listed : listed.models).find((m) => m.name === withRef.name)?.reference_steps, 8);
    await page.click("#models-refresh");
    await waitFor(async () => (await page.evaluate((n) => document.querySelector(`tr[data-model="${n}"] .checked`)?.title ?? "", withRef.name)).startsWith("8 reference steps"), { what: "the page marks its reference steps checked" });
  });

  it("pause freezes the plots while data keeps arriving", async () => {
    const page = ctx.page;
    await page.click("#pause");
    await frozenDrawn(page);
    const a = await hook.points(page, "rtob_force");
    const ca = await hook.counts(page);
    await sleep(1000);
    const b = await hook.points(page, "rtob_force");
    assert.deepEqual(b.t, a.t);
    assert.deepEqual(b.max, a.max);
    assert.ok((await hook.counts(page)).buckets > ca.buckets, "still receiving");
    await page.click("#pause");
    await waitFor(async () => (await hook.points(page, "rtob_force")).t.at(-1) > b.t.at(-1) + 0.9, { timeoutMs: 3000, what: "resume jumps to the newest data" });
  });

  it("frame times during the 10 kHz run (printed; the bar is a benchmark, not this test)", async () => {
    const page = ctx.page;
    const m = await measureFrames(page, 5000, ctx.b.userDataDir);
    console.log(`page frame times (real infer-server, 10 kHz loop): ${m.fps.toFixed(1)} fps, rAF delta p50 ${m.frameDelta.p50.toFixed(1)} ms p99 ${m.frameDelta.p99.toFixed(1)} ms; draw p50 ${m.drawMs.p50.toFixed(2)} ms p99 ${m.drawMs.p99.toFixed(2)} ms over ${m.draws} draws; Chromium CPU ${m.cpuPct.toFixed(0)} % of a core (${m.cpuMsPerFrame.toFixed(1)} ms per frame); ${m.dataFrames} data frames, ${m.buckets} buckets; load ${loadavg()[0].toFixed(1)} on ${cpus().length} cores`);
    assert.ok(m.draws > 10, "the page drew new data");
    // The committed docs/web-ui.png is refreshed only on request, so a test run leaves the tree clean.
    const shot = process.env.HAPTICS_UPDATE_SCREENSHOT === "1" ? join(repo, "docs", "web-ui.png") : join(repo, "web-ui", "test-output", "system.png");
    await mkdir(dirname(shot), { recursive: true });
    await page.screenshot({ path: shot, fullPage: true });
  });

  it("shadow started from the page: the served model's predicted force reaches the plots, and the page names the model that drew them", async () => {
    const page = ctx.page;
    assert.ok((await hook.status(page)).active_model, "a model is active (swapped in above)");
    await page.click("#exp-stop");
    await page.selectOption("#exp-kind", "shadow");
    await page.click("#exp-start");
    await waitFor(async () => (await hook.status(page)).mode === "shadow", { timeoutMs: 5000, what: "status mode shadow" });
    await waitFor(async () => finite((await hook.points(page, "F_pred")).max).length > 20, { timeoutMs: 10000, what: "F_pred on the force plot" });
    assert.equal(await page.textContent("#nodata-F_pred"), "");
    assert.ok(finite((await hook.xy(page)).y).length > 20);
    // Which model drew each point: the loop's telemetry carries the model_id of the answers it
    // used, and the strip under the force plot names the served model for the newest stretch.
    const active = (await hook.status(page)).active_model;
    const runs = await waitFor(
      async () => {
        const r = await page.evaluate(() => window.__haptics.modelRuns());
        return r.length && r.at(-1).name === active.name ? r : null;
      },
      { timeoutMs: 10000, what: `the model strip names ${active.name}` },
    );
    assert.equal(runs.at(-1).id, active.model_id, "the telemetry's model_id is the one the status gives the active model");
    assert.ok((await page.$$eval("#model-strip .run", (els) => els.map((e) => e.textContent))).includes(active.name));
    // F(t-1), the previous force the loop gives a model, reaches the page too.
    assert.ok(finite((await hook.points(page, "f_previous")).max).length > 20, "f_previous has data");
    // The hand presses the simulated object: its own force (what the model predicts) and the
    // hand's felt force (the object's plus the bench's friction and mass) are both plotted, apart.
    // (The hand rests 1 s before it presses: wait for the press.)
    await waitFor(
      async () => {
        const o = await hook.points(page, "F_object");
        const f = await hook.points(page, "F_true");
        if (finite(o.max).length < 20 || finite(f.max).length < 20) return false;
        const n = Math.min(o.max.length, f.max.length);
        for (let i = 0; i < n; i++) if (Math.abs(f.max[i] - o.max[i]) > 0.1) return true;
        return false;
      },
      { timeoutMs: 10000, what: "the felt force apart from the object's while the hand presses" },
    );
  });

  it("loop gone: the page says so, and recovers when a loop attaches again", async () => {
    const page = ctx.page;
    await page.evaluate(() => (window.__noReload = 1));
    await stop(ctx.loop);
    await waitFor(async () => (await hook.state(page)) === "loop-gone", { timeoutMs: 10000, what: "loop-gone state" });
    assert.equal(await page.isVisible("#banner"), true);
    ctx.loop = start("rt-loop", bin("rt-loop"), ctx.rtArgs);
    await waitFor(async () => (await hook.status(page)).loop_alive === true, { timeoutMs: 20000, what: "the new loop attached" });
    await startRamps(page, 2);
    await waitFor(async () => (await hook.state(page)) === "live", { timeoutMs: 20000, what: "live again after the loop restarted" });
    const c0 = (await hook.counts(page)).buckets;
    await sleep(1000);
    assert.ok((await hook.counts(page)).buckets > c0, "data flows again");
    assert.equal(await page.evaluate(() => window.__noReload), 1);
  });
});
