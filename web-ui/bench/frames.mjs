#!/usr/bin/env node
// Frame-time benchmark of the page: does it hold its draw rate (?fps=, default 30) during a 10 kHz
// run without falling behind? Prints percentiles; asserts nothing (speed is not a test).
//
//   npm run bench                       # against dev/fake-server.mjs (10 kHz, 1 ms buckets)
//   npm run bench -- --url http://127.0.0.1:8080   # against a running infer-server
//   npm run bench -- --bucket 1         # fake server sending one bucket per 10 kHz step
//
// "Falling behind" is measured as the page's newest device time advancing slower than the wall
// clock (keep-up ratio below 1) or lagging further and further behind.
import { cpus, loadavg } from "node:os";
import { startFakeServer } from "../dev/fake-server.mjs";
import { chromiumCpuSeconds, measureFrames, openBrowser, sleep, waitFor, hook } from "../tests/harness.mjs";

const a = process.argv.slice(2);
const arg = (k, d) => (a.includes(k) ? a[a.indexOf(k) + 1] : d);
const seconds = Number(arg("--seconds", 8));
let server = null;
let url = arg("--url", null);
if (!url) {
  server = await startFakeServer({ port: 0, bucket: Number(arg("--bucket", 10)), demo: true });
  url = server.url;
}
const b = await openBrowser({ width: 1440, height: 1000 });
const cdp = await b.context.newCDPSession(b.page);
await cdp.send("Performance.enable");
const metrics = async () => Object.fromEntries((await cdp.send("Performance.getMetrics")).metrics.map((x) => [x.name, x.value]));
try {
  await b.page.goto(url + "/");
  await waitFor(async () => (await hook.counts(b.page)).buckets > 100, { what: "data" });
  console.log(`page frame-time benchmark at ${url} (${server ? `fake server, bucket ${arg("--bucket", 10)} steps at 10 kHz` : "given server"}), ${seconds} s per case`);
  for (const win of ["10", "60"]) {
    await b.page.selectOption("#window", win);
    await sleep(win === "60" ? 3000 : 1000);
    const w0 = Date.now();
    const c0 = await hook.counts(b.page);
    const p0 = await metrics();
    const cpu0 = chromiumCpuSeconds(b.userDataDir);
    const m = await measureFrames(b.page, seconds * 1000);
    const p1 = await metrics();
    const cpu1 = chromiumCpuSeconds(b.userDataDir);
    const c1 = await hook.counts(b.page);
    const wall = (Date.now() - w0) / 1000;
    const keepUp = (c1.lastTime - c0.lastTime) / wall;
    // Main-thread time of the page (scripts, layout, paint records), as Chromium counts it.
    const busy = (p1.TaskDuration - p0.TaskDuration) / wall;
    const script = (p1.ScriptDuration - p0.ScriptDuration) / wall;
    const layout = (p1.LayoutDuration - p0.LayoutDuration + p1.RecalcStyleDuration - p0.RecalcStyleDuration) / wall;
    const f = (x) => x.toFixed(1);
    console.log(
      `window ${win.padStart(2)} s: ${f(m.fps)} fps | rAF delta p50 ${f(m.frameDelta.p50)} p90 ${f(m.frameDelta.p90)} p99 ${f(m.frameDelta.p99)} ms | draw p50 ${m.drawMs.p50.toFixed(2)} p90 ${m.drawMs.p90.toFixed(2)} p99 ${m.drawMs.p99.toFixed(2)} ms (${m.draws} draws) | ${m.dataFrames} data frames, ${m.buckets} buckets | keep-up ratio ${keepUp.toFixed(3)} | Chromium CPU ${((100 * (cpu1 - cpu0)) / wall).toFixed(0)} % of a core | main thread busy ${(100 * busy).toFixed(0)} % (script ${(100 * script).toFixed(0)} %, style+layout ${(100 * layout).toFixed(0)} %)`,
    );
    const want = await b.page.evaluate(() => window.__haptics.drawFps ?? 60);
    console.log(`  holds its ${want} fps of updates: ${m.fps >= 0.95 * want && keepUp > 0.98 ? "yes" : "no"} (bar: >= ${(0.95 * want).toFixed(1)} frames/s drawn and keep-up > 0.98); machine load ${loadavg()[0].toFixed(1)} on ${cpus().length} cores`);
  }
} finally {
  await b.close();
  await server?.close();
}
