// The page-only test's stand-in server (dev/fake-server.mjs) must speak the real control plane's
// schema, or the page test checks the page against something the product never sends. This
// compares it with the real control plane (infer-server's axum and WebSocket code) over the
// simulated backend, the `control-plane-sim` binary (tests/control-plane-sim), on the same
// requests: the JSON of /api/status and /api/models (every key, at every depth, with its JSON
// type), the activate answer, the WebSocket's status text frame and its binary frame header.
//
// The binary is taken from target/release (or $HAPTICS_BIN_DIR); missing, it FAILS under
// CI=true and is a counted skip elsewhere (cargo build --release -p control-plane-sim).
import { after, before, describe, test } from "node:test";
import assert from "node:assert/strict";
import { spawn } from "node:child_process";
import { existsSync } from "node:fs";
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";
import WebSocket from "ws";
import { startFakeServer } from "../dev/fake-server.mjs";
import { missing, skipMissing, waitFor } from "./harness.mjs";

const repo = resolve(dirname(fileURLToPath(import.meta.url)), "..", "..");
const binDir = process.env.HAPTICS_BIN_DIR ? resolve(process.env.HAPTICS_BIN_DIR) : join(repo, "target", "release");
const SIM = join(binDir, "control-plane-sim");

/**
 * Every key path of a JSON value with its type ("a.b:number"); a list's elements are merged
 * (`[]` in the path), a key null in one element taking the type it has in another.
 */
function shape(v, prefix = "", out = new Map()) {
  const put = (k, t) => {
    if (!out.has(k) || out.get(k) === "null") out.set(k, t);
  };
  if (Array.isArray(v)) {
    if (!prefix) put("[]", "array");
    for (const x of v) shape(x, `${prefix}[].`, out);
  } else if (v && typeof v === "object") {
    for (const [k, x] of Object.entries(v)) {
      put(`${prefix}${k}`, x === null ? "null" : Array.isArray(x) ? "array" : typeof x);
      shape(x, `${prefix}${k}.`, out);
    }
  }
  return out;
}

/**
 * The differences between two shapes. A key that is null on one side (no active model, no
 * provenance) matches any type on the other, and what lies under it is not compared.
 */
function differences(real, fake) {
  const nulls = [...real, ...fake].filter(([, t]) => t === "null").map(([k]) => `${k}.`);
  const under = (k) => nulls.some((n) => k.startsWith(n));
  const out = [];
  for (const k of new Set([...real.keys(), ...fake.keys()])) {
    if (under(k)) continue;
    const a = real.get(k);
    const b = fake.get(k);
    if (a === undefined) out.push(`only the fake sends ${k} (${b})`);
    else if (b === undefined) out.push(`the fake lacks ${k} (${a})`);
    else if (a !== b && a !== "null" && b !== "null") out.push(`${k}: ${a} from the control plane, ${b} from the fake`);
  }
  return out.sort();
}

/** The first text (parsed) and the first binary frame of the telemetry WebSocket. */
function firstFrames(url) {
  return new Promise((res, rej) => {
    const ws = new WebSocket(`${url.replace(/^http/, "ws")}/ws/telemetry?fps=30`);
    let text = null;
    let bin = null;
    const timer = setTimeout(() => (ws.terminate(), rej(new Error(`no text and binary frame from ${url} in 10 s`))), 10000);
    ws.on("message", (d, isBinary) => {
      if (isBinary) bin ??= Buffer.from(d);
      else text ??= JSON.parse(d.toString());
      if (text && bin) {
        clearTimeout(timer);
        ws.close();
        res({ text, bin });
      }
    });
    ws.on("error", rej);
  });
}

describe("the fake server speaks the control plane's schema", () => {
  let skipWhy = null;
  let sim = null;
  let fake = null;
  let real = "";
  /** The answers to the activation of the same model on the control plane and on the fake. */
  const activations = [];

  before(async () => {
    if (!existsSync(SIM)) {
      skipWhy = missing(`${SIM} not found (cargo build --release -p control-plane-sim, or set HAPTICS_BIN_DIR)`);
      return;
    }
    sim = spawn(SIM, ["--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0"], { stdio: ["ignore", "pipe", "pipe"] });
    let out = "";
    sim.stdout.on("data", (d) => (out += d));
    sim.stderr.on("data", (d) => (out += d));
    real = await waitFor(() => out.match(/HTTP (http:\/\/\S+)/)?.[1], { what: `control-plane-sim's addresses (output: ${out})` });
    fake = await startFakeServer({ port: 0 });
    // One model active on both, so the status's active_model is an object on both sides.
    for (const url of [real, fake.url]) {
      const models = await (await fetch(`${url}/api/models`)).json();
      const r = await fetch(`${url}/api/models/${encodeURIComponent(models.at(-1).name)}/activate`, { method: "POST" });
      const body = await r.text();
      assert.equal(r.status, 200, `activate on ${url}: ${body}`);
      activations.push(JSON.parse(body));
    }
  });

  after(async () => {
    sim?.kill("SIGINT");
    await fake?.close();
  });

  const it = (name, fn) =>
    test(name, async (t) => {
      // Under CI `missing()` already threw in before(); skipMissing fails here too if not.
      if (skipWhy) return skipMissing(t, skipWhy);
      await fn();
    });

  it("/api/status and /api/models: the same keys with the same types", async () => {
    for (const path of ["/api/status", "/api/models"]) {
      const [a, b] = await Promise.all([real, fake.url].map(async (u) => (await fetch(u + path)).json()));
      assert.deepEqual(differences(shape(a), shape(b)), [], `${path} of the fake differs from the control plane's`);
    }
  });

  it("the activate answer has the same keys", async () => {
    const [a, b] = activations;
    assert.deepEqual(differences(shape(a), shape(b)), []);
  });

  it("the WebSocket: a status text frame like /api/status, and binary frames of the same format", async () => {
    const [a, b] = await Promise.all([firstFrames(real), firstFrames(fake.url)]);
    assert.equal(a.text.type, "status");
    assert.deepEqual(differences(shape(a.text), shape(b.text)), []);
    for (const [who, f] of [["control plane", a.bin], ["fake", b.bin]]) {
      assert.equal(f.toString("latin1", 0, 4), "HPT1", `${who}: magic`);
      assert.equal(f.readUInt16LE(4), 1, `${who}: version`);
      const S = f.readUInt16LE(6);
      const B = f.readUInt32LE(8);
      assert.equal(f.length, 16 + 8 * B + 8 * B * S, `${who}: length of ${B} buckets of ${S} series`);
    }
    // The fake sends every series the page knows; the control plane as many.
    const sReal = a.bin.readUInt16LE(6);
    const sFake = b.bin.readUInt16LE(6);
    assert.equal(sFake, sReal, `series per bucket: the fake sends ${sFake}, the control plane ${sReal}`);
  });
});
