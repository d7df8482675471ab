#!/usr/bin/env bash
# Python side of the set-up, idempotent: a virtual environment with numpy, onnx (graph checks),
# onnxruntime (whose wheel also carries libonnxruntime.so for the Rust renderer: ort,
# load-dynamic), Pillow and pytest, and the project's Python package (python/, nerf_bundle,
# editable). For the distributed examples' tests (tests/shards.rs): Ray (examples/ray runs on a
# local Ray cluster), PyYAML (the Kubernetes manifests) and kubernetes-validate (Kubernetes'
# OpenAPI schemas, offline: what `kubectl apply --dry-run=client` checks a Job against).
# Everything lives under ~/.cache/nerf-rs (override with NERF_HOME).
set -euo pipefail
NERF_HOME="${NERF_HOME:-$HOME/.cache/nerf-rs}"
VENV="$NERF_HOME/venv"
STAMP="$VENV/.nerf-rs-requirements"
REQUIREMENTS="numpy onnx onnxruntime==1.31.1 Pillow pytest wheel pyyaml==6.0.3 ray==2.60.0 kubernetes-validate==1.37.0"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$REQUIREMENTS" ]; then
  PYTHON="${PYTHON:-python3}"
  command -v "$PYTHON" >/dev/null || { echo "python3 not found: install Python ≥ 3.9 first" >&2; exit 1; }
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check $REQUIREMENTS
  echo "$REQUIREMENTS" > "$STAMP"
fi

# The Python package, editable: python/ is used as it is.
if ! "$VENV/bin/python" -c "import nerf_bundle" >/dev/null 2>&1; then
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps -e "$(cd "$(dirname "$0")/.." && pwd)/python"
fi

# The browser viewer (`nerf-render --serve`): TypeScript built with npm from viewer/'s lockfile,
# installed into $NERF_HOME/viewer (where nerf-render looks for it). Needs Node.js ≥ 18.
REPO="$(cd "$(dirname "$0")/.." && pwd)"
if command -v npm >/dev/null 2>&1; then
  (
    cd "$REPO/viewer"
    LOCK_STAMP="node_modules/.nerf-rs-lock"
    if [ ! -f "$LOCK_STAMP" ] || ! cmp -s package-lock.json "$LOCK_STAMP"; then
      npm ci --no-audit --no-fund --loglevel=error
      cp package-lock.json "$LOCK_STAMP"
    fi
    npm run --silent build >/dev/null
  )
  rm -rf "$NERF_HOME/viewer.new"
  cp -r "$REPO/viewer/dist" "$NERF_HOME/viewer.new"
  rm -rf "$NERF_HOME/viewer"
  mv "$NERF_HOME/viewer.new" "$NERF_HOME/viewer"
else
  echo "note: npm not found, so the browser viewer (nerf-render --serve) is not built: install Node.js ≥ 18 and run this again" >&2
fi
