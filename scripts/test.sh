#!/usr/bin/env bash
# Build and run the whole test suite (release mode: NeRF training is too slow unoptimised).
# The lego tests read ../shared/data/nerf_synthetic/lego; the export tests run
# tests/python/check_graphs.py with the Python environment from scripts/setup.sh; the viewer's
# browser tests need Debian's chromium at /usr/bin/chromium (.ci/run installs it).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh   # numpy, onnx, onnxruntime for the graph checks (idempotent)
. scripts/env.sh
cargo test --release --workspace "$@"
# The browser viewer: its types (tsc; vite builds without checking them), unit tests (vitest)
# and, in headless chromium, the pages served by nerf-render --serve against nerf-render's own
# frames (viewer/tests/browser.test.mjs).
(cd viewer && npm run --silent typecheck && npm run --silent test:unit && npm run --silent test:browser)
# The Python package against nerf-render's frames, its bad-bundle refusals, and its wheel; the
# native loop setup.sh built must be there (test_native_module.py).
NERF_REQUIRE_NATIVE=1 "$NERF_PYTHON" -m pytest -q python/tests
