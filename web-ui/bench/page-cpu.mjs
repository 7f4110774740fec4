#!/usr/bin/env node
// What the page costs the machine: CPU seconds used by all of headless Chromium's processes
// (browser, renderer, GPU, utility; from /proc/<pid>/stat) per second of wall time, while the page
// shows a running system, then while its tab is hidden (another tab brought to the front).
// Prints the figures and, last, one JSON object; asserts nothing (speed is not a test).
//
//   node bench/page-cpu.mjs --url http://127.0.0.1:8080 [--seconds 20]
//   node bench/page-cpu.mjs --url ... --hold     # keep the page open (visible) until SIGUSR2,
//                                                # then print the figures (scripts/bench-loaded.sh)
//   node bench/page-cpu.mjs --url ... --no-data  # a server without a loop: nothing new arrives
// Headless Chromium keeps a tab "visible" when another is brought to the front (the JSON's
// hidden_state says which it was), so the hidden figure is only meaningful where it says hidden.
import { chromiumCpuSeconds, hook, openBrowser, sleep, waitFor } from "../tests/harness.mjs";

const a = process.argv.slice(2);
const arg = (k, d) => (a.includes(k) ? a[a.indexOf(k) + 1] : d);
const url = arg("--url", "http://127.0.0.1:8080");
const seconds = Number(arg("--seconds", 20));
const hold = a.includes("--hold");
const noData = a.includes("--no-data");

const b = await openBrowser({ width: 1440, height: 1000 });
const result = { url, visible_cpu_per_s: null, hidden_cpu_per_s: null, draws_per_s: null, data_frames_per_s: null, draw_fps: null, hidden_state: null };
try {
  // An address with the token in its fragment (`http://host:port/#token=...`, what infer-server
  // prints and scripts/up.sh shows) is opened as it is; a bare one gets the page's path.
  await b.page.goto(url.includes("#") ? url : url + "/");
  if (noData) await waitFor(async () => (await hook.state(b.page)) !== "connecting", { what: "the page's first status" });
  else await waitFor(async () => (await hook.counts(b.page)).buckets > 100, { what: "telemetry on the page", timeoutMs: 30000 });
  await sleep(1000);
  result.draw_fps = await b.page.evaluate(() => window.__haptics.drawFps ?? 60);

  // Visible: for --seconds, or until SIGTERM/SIGINT with --hold.
  const t0 = Date.now();
  const cpu0 = chromiumCpuSeconds(b.userDataDir);
  const c0 = await hook.counts(b.page);
  const f0 = (await hook.frameTimes(b.page)).length;
  if (hold) {
    // SIGUSR2: playwright closes the browser itself on SIGTERM/SIGINT, before we could read it.
    await new Promise((resolve) => process.once("SIGUSR2", resolve));
  } else {
    await sleep(seconds * 1000);
  }
  const wall = (Date.now() - t0) / 1000;
  const cpu1 = chromiumCpuSeconds(b.userDataDir);
  const c1 = await hook.counts(b.page);
  // frameTimes keeps the last 2000 deltas: count the draws from the wall time when it is full.
  const f1 = (await hook.frameTimes(b.page)).length;
  result.visible_cpu_per_s = (cpu1 - cpu0) / wall;
  result.data_frames_per_s = (c1.frames - c0.frames) / wall;
  result.draws_per_s = f1 < 2000 ? (f1 - f0) / wall : null;
  result.visible_seconds = wall;

  if (!hold) {
    // Hidden: another tab in front (the page's document.visibilityState becomes "hidden").
    const other = await b.context.newPage();
    await other.goto("about:blank");
    await other.bringToFront();
    await sleep(1500);
    result.hidden_state = await b.page.evaluate(() => document.visibilityState);
    const h0 = chromiumCpuSeconds(b.userDataDir);
    const th = Date.now();
    await sleep(seconds * 1000);
    result.hidden_cpu_per_s = (chromiumCpuSeconds(b.userDataDir) - h0) / ((Date.now() - th) / 1000);
  }
} finally {
  await b.close();
}
const f = (x) => (x === null || Number.isNaN(x) ? "n/a" : x.toFixed(3));
console.log(
  `page CPU at ${url}: visible ${f(result.visible_cpu_per_s)} CPU-s/s (${f(result.draws_per_s)} draws/s at most ${result.draw_fps}, ${f(result.data_frames_per_s)} telemetry frames/s)` +
    (hold ? "" : `; hidden (${result.hidden_state}) ${f(result.hidden_cpu_per_s)} CPU-s/s`),
);
console.log(JSON.stringify(result));
