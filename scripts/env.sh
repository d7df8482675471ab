# Shared by the scripts: one persistent build directory outside the clone, so a second clone or
# a CI run on the same machine reuses the ≈20-minute burn build. Override with CARGO_TARGET_DIR.
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/nerf-rs/target}"
export CARGO_TERM_COLOR="${CARGO_TERM_COLOR:-never}"
if ! command -v cargo >/dev/null 2>&1; then
  if [ -f "$HOME/.cargo/env" ]; then . "$HOME/.cargo/env"; fi
fi
command -v cargo >/dev/null 2>&1 || { echo "cargo not found: install Rust (https://rustup.rs) first" >&2; exit 1; }
# The Python environment from scripts/setup.sh, and onnxruntime's library from its wheel.
export NERF_HOME="${NERF_HOME:-$HOME/.cache/nerf-rs}"
export NERF_PYTHON="${NERF_PYTHON:-$NERF_HOME/venv/bin/python}"
if [ -z "${ORT_DYLIB_PATH:-}" ]; then
  for lib in "$NERF_HOME"/venv/lib/python3*/site-packages/onnxruntime/capi/libonnxruntime.so*; do
    [ -e "$lib" ] && export ORT_DYLIB_PATH="$lib"
  done
fi
