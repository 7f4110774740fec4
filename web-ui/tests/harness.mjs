// Shared helpers for the browser tests: Debian's Chromium driven by playwright-core (no browser
// download, ever), a fresh profile per run, and the page's read-only test hook.
import { mkdtemp, rm } from "node:fs/promises";
import { existsSync, readdirSync, readFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { createServer } from "node:net";
import { chromium } from "playwright-core";
import { runnerImport } from "vite";

/** The generated vocabulary (src/vocab.ts, from proto/): series, phase and feature names. */
export const { module: vocab } = await runnerImport(join(dirname(fileURLToPath(import.meta.url)), "..", "src", "vocab.ts"));

export const CHROMIUM = process.env.CHROMIUM_PATH ?? "/usr/bin/chromium";
const ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update", "--no-first-run", "--disable-sync", "--disable-dev-shm-usage"];

/**
 * Starts Chromium with a new temporary profile (and `args` besides the usual ones). Returns
 * { context, page, requests, close }.
 * `requests` records every URL the page asked for, so a test can check that nothing left the
 * server the page came from.
 */
export async function openBrowser({ width = 1440, height = 1000, args = [] } = {}) {
  if (!existsSync(CHROMIUM)) throw new Error(`${CHROMIUM} not found: install Debian's chromium (apt-get install -y chromium); the tests never download a browser`);
  const userDataDir = await mkdtemp(join(tmpdir(), "haptics-chromium-"));
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: CHROMIUM,
    headless: true,
    args: [...ARGS, ...args],
    viewport: { width, height },
    acceptDownloads: true,
  });
  const page = context.pages()[0] ?? (await context.newPage());
  const requests = [];
  const consoleErrors = [];
  page.on("request", (r) => requests.push(r.url()));
  page.on("console", (m) => {
    if (m.type() === "error") consoleErrors.push(m.text());
  });
  page.on("pageerror", (e) => consoleErrors.push(String(e)));
  return {
    context,
    page,
    requests,
    consoleErrors,
    userDataDir,
    async close() {
      await context.close().catch(() => {});
      await rm(userDataDir, { recursive: true, force: true }).catch(() => {});
    },
  };
}

/**
 * A dependency of a test is missing (a binary, a browser): under CI=true that FAILS (throws);
 * elsewhere it returns `why`, for the caller to skip with (node:test counts skips, and
 * scripts/test.sh prints the count).
 */
export function missing(why) {
  if (process.env.CI === "true") throw new Error(`${why} (CI=true: a test that cannot run fails)`);
  return why;
}

/**
 * The one place a test skips for a missing dependency: under CI=true it throws, so the test
 * FAILS even where `missing()` was not reached first; elsewhere a counted node:test skip.
 */
export function skipMissing(t, why) {
  missing(why);
  return t.skip(why);
}

/** A TCP port free on 127.0.0.1 right now (for a server the test starts). */
export async function freePort() {
  return new Promise((res, rej) => {
    const s = createServer();
    s.once("error", rej);
    s.listen(0, "127.0.0.1", () => {
      const p = s.address().port;
      s.close(() => res(p));
    });
  });
}

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** Polls `fn` until it returns a truthy value or the time is up; returns the last value. */
export async function waitFor(fn, { timeoutMs = 10000, everyMs = 100, what = "condition" } = {}) {
  const end = Date.now() + timeoutMs;
  let v;
  while (Date.now() < end) {
    v = await fn();
    if (v) return v;
    await sleep(everyMs);
  }
  throw new Error(`timed out after ${timeoutMs} ms waiting for ${what} (last value: ${JSON.stringify(v)?.slice(0, 300)})`);
}

export const hook = {
  points: (page, name) => page.evaluate((n) => window.__haptics.points(n), name),
  xy: (page) => page.evaluate(() => window.__haptics.xy()),
  frameTimes: (page) => page.evaluate(() => window.__haptics.frameTimes()),
  drawTimes: (page) => page.evaluate(() => window.__haptics.drawTimes()),
  paused: (page) => page.evaluate(() => window.__haptics.paused),
  state: (page) => page.evaluate(() => window.__haptics.state),
  status: (page) => page.evaluate(() => window.__haptics.status()),
  counts: (page) => page.evaluate(() => window.__haptics.counts()),
};

/**
 * Waits until the plots have drawn the frozen range. Pausing freezes the range shown at the
 * click, but the plots draw on their own clock (at most 30 times a second, later on a loaded
 * machine): data that arrived between the last live frame and the click moves the right edge, so
 * what the plots show is only the frozen view once that frame is drawn.
 */
export async function frozenDrawn(page) {
  await waitFor(
    async () => {
      const v = await page.evaluate(() => window.__haptics.view());
      return v.frozen && v.drawn && v.drawn[0] === v.range[0] && v.drawn[1] === v.range[1];
    },
    { timeoutMs: 3000, what: "the frozen range drawn" },
  );
}

export function percentiles(xs, qs = [0.5, 0.9, 0.99]) {
  const s = [...xs].sort((a, b) => a - b);
  return Object.fromEntries(qs.map((q) => [`p${Math.round(q * 1000) / 10}`, s.length ? s[Math.min(s.length - 1, Math.floor(q * s.length))] : NaN]));
}

/** Finite values of a points() series (gaps are NaN). */
export const finite = (xs) => xs.filter(Number.isFinite);

/** Area enclosed by a path (shoelace, closed from last to first point). */
export function enclosedArea(x, y) {
  let a = 0;
  for (let i = 0; i < x.length; i++) {
    const j = (i + 1) % x.length;
    a += x[i] * y[j] - x[j] * y[i];
  }
  return a / 2;
}

/** The frame-time figures every browser test prints: rAF deltas and draw times over a period. */
export async function measureFrames(page, ms = 5000, userDataDir = null) {
  const before = (await hook.frameTimes(page)).length;
  const beforeDraw = (await hook.drawTimes(page)).length;
  const c0 = await hook.counts(page);
  const cpu0 = userDataDir ? chromiumCpuSeconds(userDataDir) : NaN;
  await sleep(ms);
  const cpu1 = userDataDir ? chromiumCpuSeconds(userDataDir) : NaN;
  const ft = await hook.frameTimes(page);
  const dt = await hook.drawTimes(page);
  const c1 = await hook.counts(page);
  const fr = ft.slice(Math.max(0, ft.length - (ft.length - before)));
  const dr = dt.slice(Math.max(0, dt.length - (dt.length - beforeDraw)));
  return {
    frames: fr.length,
    fps: (fr.length * 1000) / ms,
    frameDelta: percentiles(fr),
    draws: dr.length,
    drawMs: percentiles(dr),
    dataFrames: c1.frames - c0.frames,
    buckets: c1.buckets - c0.buckets,
    /** Chromium's CPU use over the period, in % of one core, and per drawn frame (ms). */
    cpuPct: (100 * (cpu1 - cpu0)) / (ms / 1000),
    cpuMsPerFrame: (1000 * (cpu1 - cpu0)) / Math.max(1, fr.length),
  };
}

/**
 * CPU seconds (user + system) used so far by this test's Chromium: the browser process (found by
 * its --user-data-dir) and all its descendants (renderer, GPU, utility). Unlike frame times this
 * does not depend on how busy the rest of the machine is. Linux only; NaN elsewhere.
 */
export function chromiumCpuSeconds(userDataDir) {
  try {
    const hz = 100; // USER_HZ on Linux
    const procs = new Map();
    for (const d of readdirSync("/proc")) {
      if (!/^\d+$/.test(d)) continue;
      try {
        const stat = readFileSync(`/proc/${d}/stat`, "utf8");
        const f = stat.slice(stat.lastIndexOf(")") + 2).split(" ");
        procs.set(Number(d), { ppid: Number(f[1]), cpu: (Number(f[11]) + Number(f[12])) / hz, cmd: null });
      } catch {
        /* gone meanwhile */
      }
    }
    const roots = [...procs.keys()].filter((pid) => {
      try {
        return readFileSync(`/proc/${pid}/cmdline`, "utf8").includes(`--user-data-dir=${userDataDir}`);
      } catch {
        return false;
      }
    });
    const mine = new Set(roots);
    let grew = true;
    while (grew) {
      grew = false;
      for (const [pid, p] of procs) if (!mine.has(pid) && mine.has(p.ppid)) mine.add(pid), (grew = true);
    }
    let total = 0;
    for (const pid of mine) total += procs.get(pid).cpu;
    return mine.size ? total : NaN;
  } catch {
    return NaN;
  }
}
