// Builds the page (`npm run build`) only when a source is newer than dist/index.html, the same
// rule as scripts/setup.sh. `npm test` used to rebuild unconditionally, which left dist/ newer
// than the infer-server binary that embeds it, so the next `cargo build` (scripts/up.sh right
// after scripts/test.sh) recompiled infer-server for an identical page.
import { execSync } from "node:child_process";
import { existsSync, readdirSync, statSync } from "node:fs";
import { join } from "node:path";

const root = new URL("..", import.meta.url).pathname;
const built = join(root, "dist/index.html");
const sources = ["src", "index.html", "vite.config.ts", "tsconfig.json", "package-lock.json"];

function newest(path) {
  const st = statSync(path);
  if (!st.isDirectory()) return st.mtimeMs;
  return Math.max(st.mtimeMs, ...readdirSync(path).map((n) => newest(join(path, n))));
}

const stale =
  !existsSync(built) ||
  sources.some((s) => existsSync(join(root, s)) && newest(join(root, s)) > statSync(built).mtimeMs);
if (stale) {
  execSync("npm run build --silent", { cwd: root, stdio: "inherit" });
} else {
  console.log("web-ui: dist/ is newer than its sources; not rebuilt");
}
