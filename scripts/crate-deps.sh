#!/usr/bin/env bash
# The workspace's crates and which of them each depends on (from `cargo metadata`, nothing
# hand-written), and a check of the layers docs/architecture.md states:
#   - shm-ring (the generic rings and segment) depends on no crate of this workspace;
#   - haptics-proto (the vocabulary) on shm-ring only;
#   - the two processes never depend on each other: rt-loop not on infer-server or
#     control-plane, infer-server and control-plane not on rt-loop;
#   - haptics-fused-ops on no crate of this workspace, haptics-ort-host (ONNX Runtime hosted
#     for both processes) on haptics-fused-ops only;
#   - hapticctl not on control-plane (the generated gRPC types come from haptics-proto);
#   - no shipped crate on a test-support crate.
# Dev-dependencies (tests, benches) are listed but not held to the layers.
#
#   bash scripts/crate-deps.sh            # print the edges
#   bash scripts/crate-deps.sh --check    # print, then exit 1 if a layer is broken
set -euo pipefail
cd "$(dirname "$0")/.."
python3 - "$@" <<'PY'
import json, subprocess, sys

check = "--check" in sys.argv[1:]
meta = json.loads(subprocess.run(
    ["cargo", "metadata", "--format-version", "1", "--no-deps"],
    check=True, capture_output=True, text=True).stdout)
ours = {p["name"] for p in meta["packages"]}
deps = {}
for p in sorted(meta["packages"], key=lambda p: p["name"]):
    normal = sorted({d["name"] for d in p["dependencies"] if d["name"] in ours and d["kind"] is None})
    other = sorted({d["name"] for d in p["dependencies"]
                    if d["name"] in ours and d["kind"] is not None} - set(normal))
    deps[p["name"]] = set(normal)
    line = f"{p['name']:22} -> {', '.join(normal) or '-'}"
    if other:
        line += f"   (tests/benches: {', '.join(other)})"
    print(line)

TEST_SUPPORT = {"haptics-system-tests", "shm-ring-testing", "control-plane-sim", "shm-ring-bench-grpc", "s826-double"}
FORBIDDEN = {
    "shm-ring": ours - {"shm-ring"},
    "haptics-proto": ours - {"haptics-proto", "shm-ring"},
    "haptics-fused-ops": ours - {"haptics-fused-ops"},
    "haptics-ort-host": ours - {"haptics-ort-host", "haptics-fused-ops"},
    "rt-loop": {"infer-server", "control-plane", "hapticctl"},
    "infer-server": {"rt-loop", "hapticctl"},
    "control-plane": {"rt-loop", "infer-server", "hapticctl"},
    "hapticctl": {"control-plane", "infer-server", "rt-loop"},
}
broken = []
for name, used in deps.items():
    bad = used & FORBIDDEN.get(name, set())
    if name not in TEST_SUPPORT:
        bad |= used & TEST_SUPPORT
    broken += [f"{name} depends on {b}" for b in sorted(bad)]
if broken:
    print("layers broken (docs/architecture.md): " + "; ".join(broken), file=sys.stderr)
    sys.exit(1 if check else 0)
if check:
    print("layers: ok")
PY
