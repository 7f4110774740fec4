#!/usr/bin/env node
// Writes docs/web-ui.png: the whole page after a few seconds of ramp cycles.
//   node bench/screenshot.mjs                   # from dev/fake-server.mjs (synthetic sponge)
//   node bench/screenshot.mjs --url 'http://127.0.0.1:8080/#token=...'   # from a running
//        infer-server: the page's address as scripts/up.sh prints it, token included
// tests/system.test.mjs writes the same file from the real processes when they run.
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import { startFakeServer } from "../dev/fake-server.mjs";
import { openBrowser, sleep, waitFor, hook } from "../tests/harness.mjs";

const a = process.argv.slice(2);
const out = a.includes("--out") ? a[a.indexOf("--out") + 1] : join(dirname(fileURLToPath(import.meta.url)), "..", "..", "docs", "web-ui.png");
let url = a.includes("--url") ? a[a.indexOf("--url") + 1] : null;
const server = url ? null : await startFakeServer({ port: 0, demo: true });
url ??= server.url;
const b = await openBrowser({ width: 1440, height: 1000 });
try {
  // the address as printed carries the token in its fragment: an appended "/" would spoil it
  await b.page.goto(new URL(url).pathname === "/" && !url.endsWith("/") && !url.includes("#") ? url + "/" : url);
  await waitFor(async () => (await hook.counts(b.page)).buckets > 100, { what: "data" });
  await sleep(12000);
  await b.page.screenshot({ path: out, fullPage: true });
  console.log(`wrote ${out}`);
} finally {
  await b.close();
  await server?.close();
}
