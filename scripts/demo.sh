#!/usr/bin/env bash
# Build (release) and run the built-in demo: generate a scene, train, evaluate, render an orbit.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/env.sh
cargo build --release --bin nerf
exec "$CARGO_TARGET_DIR/release/nerf" demo "$@"
