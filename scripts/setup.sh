#!/usr/bin/env bash
# Installs everything the project needs from the package registries, idempotently:
#   - .venv with the train/ package (and onnxruntime, whose wheel ships libonnxruntime.so)
#   - .ort/libonnxruntime.so, the library `ort` loads dynamically (ORT_DYLIB_PATH)
#   - web-ui's npm packages (`npm ci`: exactly package-lock.json) and Debian's chromium (for the
#     browser tests; skipped with HAPTICS_NO_BROWSER=1, as scripts/up.sh does)
#   - the page itself, web-ui/dist (a build output, not committed): control-plane's build.rs
#     embeds it when cargo compiles infer-server, so scripts/test.sh and scripts/up.sh run this
#     script BEFORE any cargo command; rebuilt when a source of the page is newer than it
# Nothing is downloaded from anywhere but crates.io, PyPI, npm and Debian's archive.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ -f train/pyproject.toml ]; then
  if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv"
    python3 -m venv .venv
  fi
  stamp=.venv/.train-installed
  # The exact pins of train/pyproject.toml (onnxruntime: the library infer-server loads; torch;
  # onnx; skl2onnx) must be what .venv holds: a venv kept from before a pin changed is reinstalled.
  if [ -f "$stamp" ] && ! .venv/bin/python - <<'PY'; then
import re, sys
from importlib.metadata import PackageNotFoundError, version
pins = re.findall(r'"([A-Za-z0-9_.-]+)==([^"]+)"', open("train/pyproject.toml").read())
bad = []
for name, want in pins:
    try:
        have = version(name)
    except PackageNotFoundError:
        have = "missing"
    if have.split("+")[0] != want:
        bad.append(f"{name} {have} (pinned {want})")
if bad:
    print("setup: .venv differs from the pins: " + ", ".join(bad))
    sys.exit(1)
PY
    rm -f "$stamp"
  fi
  if [ ! -f "$stamp" ] || [ train/pyproject.toml -nt "$stamp" ]; then
    echo "setup: installing train/ into .venv (first time: PyTorch is large, a few minutes)"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e 'train[dev]'
    touch "$stamp"
  fi
fi

# The Python client (`haptics`, client/; docs/python.md) with the example notebook's packages.
# Its gRPC code is generated from proto/haptics/v1/haptics.proto when it is installed: installed
# again when its pyproject/setup.py or the .proto is newer than the last install, or when the
# generated code is missing (a fresh clone of a kept .venv).
if [ -f client/pyproject.toml ] && [ -x .venv/bin/python ]; then
  stamp=.venv/.client-installed
  if [ ! -f "$stamp" ] || [ ! -f client/src/haptics/v1/haptics_pb2.py ] \
    || [ -n "$(find client/pyproject.toml client/setup.py proto/haptics/v1/haptics.proto -newer "$stamp" -print -quit)" ] \
    || ! grep -qs "$(sha256sum proto/haptics/v1/haptics.proto | cut -d' ' -f1)" client/src/haptics/v1/__init__.py; then
    echo "setup: installing the Python client (client/, generating its gRPC code) into .venv"
    .venv/bin/python -m pip install -q -e 'client[notebook,dev]'
    touch "$stamp"
  fi
fi

# Again when the venv was (re)installed since: the pinned wheel may have changed version.
if [ ! -f .ort/libonnxruntime.so ] || [ .venv/.train-installed -nt .ort/libonnxruntime.so ]; then
  lib=""
  if [ -x .venv/bin/python ]; then
    lib=$(.venv/bin/python - <<'PY' 2>/dev/null || true
import glob, os
try:
    import onnxruntime
except ImportError:
    raise SystemExit(1)
d = os.path.join(os.path.dirname(onnxruntime.__file__), "capi")
libs = sorted(glob.glob(os.path.join(d, "libonnxruntime.so*")))
print(libs[0] if libs else "")
PY
)
  fi
  if [ -n "$lib" ]; then
    mkdir -p .ort
    cp -L "$lib" .ort/libonnxruntime.so
    echo "setup: ONNX Runtime library at .ort/libonnxruntime.so (from the onnxruntime wheel)"
  fi
fi

if [ -f web-ui/package.json ]; then
  # Also when package-lock.json changed since the last install (a machine kept between sessions).
  if [ ! -d web-ui/node_modules ] || [ web-ui/package-lock.json -nt web-ui/node_modules/.package-lock.json ]; then
    echo "setup: npm ci in web-ui/"
    (cd web-ui && npm ci --no-audit --no-fund)
  fi
  if [ ! -x /usr/bin/chromium ] && [ "${HAPTICS_NO_BROWSER:-0}" != 1 ]; then
    echo "setup: installing Debian's chromium for the browser tests"
    if [ "$(id -u)" = 0 ]; then
      apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    else
      sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    fi
  fi
  # The page. `npm run build` rewrites dist/index.html, so it is the build's time stamp; cargo
  # sees the new files (build.rs: rerun-if-changed on dist/) and embeds them at its next build.
  built=web-ui/dist/index.html
  if [ ! -f "$built" ] || [ -n "$(find web-ui/src web-ui/index.html web-ui/vite.config.ts \
    web-ui/tsconfig.json web-ui/package-lock.json -newer "$built" -print -quit)" ]; then
    echo "setup: building the page (web-ui/dist, embedded by infer-server at its build)"
    (cd web-ui && npm run build --silent)
  fi
fi
