#!/usr/bin/env bash
# Python side of the set-up, idempotent: a virtual environment with numpy, onnx (graph checks)
# and onnxruntime, whose wheel also carries libonnxruntime.so for the Rust renderer (ort,
# load-dynamic). Everything lives under ~/.cache/nerf-rs (override with NERF_HOME).
set -euo pipefail
NERF_HOME="${NERF_HOME:-$HOME/.cache/nerf-rs}"
VENV="$NERF_HOME/venv"
STAMP="$VENV/.nerf-rs-requirements"
REQUIREMENTS="numpy onnx onnxruntime==1.31.1"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$REQUIREMENTS" ]; then
  PYTHON="${PYTHON:-python3}"
  command -v "$PYTHON" >/dev/null || { echo "python3 not found: install Python ≥ 3.9 first" >&2; exit 1; }
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check $REQUIREMENTS
  echo "$REQUIREMENTS" > "$STAMP"
fi
