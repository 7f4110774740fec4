// The page is served by infer-server from `web-ui/dist` (embedded at build time), so the build
// must be self-contained: no CDN, no web fonts, relative asset paths, content-hashed names.
import { defineConfig } from "vite";

// During `npm run dev` the API and the WebSocket go to a server on 127.0.0.1:8080
// (infer-server, or `npm run fake-server`).
const backend = process.env.HAPTICS_BACKEND ?? "http://127.0.0.1:8080";

export default defineConfig({
  base: "./",
  build: {
    outDir: "dist",
    emptyOutDir: true,
    sourcemap: false,
    // Small enough that inlining tiny assets does not matter; keep files separate and hashed.
    assetsInlineLimit: 0,
    reportCompressedSize: false,
  },
  server: {
    proxy: {
      "/api": backend,
      "/metrics": backend,
      "/ws": { target: backend.replace(/^http/, "ws"), ws: true },
    },
  },
});
