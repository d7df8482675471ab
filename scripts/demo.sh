#!/usr/bin/env bash
# Set up, build (release) and run the built-in demo: generate a scene, train, evaluate, render an
# orbit with burn; then export the run to ONNX and render the orbit again with nerf-render
# (onnxruntime). Arguments go to `nerf demo` (e.g. --minutes 1).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh   # Python venv with onnxruntime (nerf-render loads its libonnxruntime.so)
. scripts/env.sh
cargo build --release -p nerf --bin nerf -p nerf-runtime --bin nerf-render
OUT=demo-out
args=("$@")
for ((k = 0; k < ${#args[@]}; k++)); do
  [ "${args[$k]}" = "--out" ] && OUT="${args[$((k + 1))]}"
done
"$CARGO_TARGET_DIR/release/nerf" demo "$@"
"$CARGO_TARGET_DIR/release/nerf" export --run "$OUT/run" --out "$OUT/bundle"
"$CARGO_TARGET_DIR/release/nerf-render" --bundle "$OUT/bundle" --orbit --out "$OUT/ort-orbit"
