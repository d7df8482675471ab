#!/usr/bin/env bash
# Build and run the whole test suite (release mode: NeRF training is too slow unoptimised).
# The lego tests read ../shared/data/nerf_synthetic/lego.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/env.sh
cargo test --release --workspace "$@"
