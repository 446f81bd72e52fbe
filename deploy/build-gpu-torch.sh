#!/usr/bin/env bash
# Builds the learner and the actor on libtorch (burn's `tch` backend on CUDA,
# `nets/gpu-torch` and `training/gpu-torch`; docs/decisions/0010-libtorch-on-a-gpu.md). See --help.
set -euo pipefail

usage() {
  cat <<'USAGE'
Usage: deploy/build-gpu-torch.sh [options]

Builds release binaries whose `--device gpu` runs the networks on libtorch's
CUDA kernels, and copies them into one directory for deploy/local.sh
--bin-dir or deploy/gpu-check.sh --bin-dir. libtorch must be the PyTorch
version of the machine they will run on: its C++ ABI changes between
releases. At run time they load libtorch through LD_LIBRARY_PATH, which
local.sh, actors.sh and gpu-check.sh point at python3's torch when needed.

Options:
  --torch VERSION  PyTorch release whose libtorch to build against (default
                   2.11.0, the lent GPU machines'); its wheel is fetched from
                   PyPI with pip and unpacked under --cache (about 1 GB)
  --libtorch DIR   use this libtorch instead (a directory with include/ and
                   lib/, e.g. a torch package's directory)
  --cache DIR      where fetched libtorch goes (default ~/.cache/afx-libtorch)
  --out DIR        where the binaries go (default target/gpu-torch)
  --checks         also the GPU checks' binaries: the training, env_steps,
                   unet_inference, ppo_batches and adam_steps benches, the CPU/GPU
                   agreement test and the gateway (for gpu-check.sh)
  --strip          strip the binaries (to carry them to another machine)
  -h, --help       this help
USAGE
}

TORCH=2.11.0 LIBTORCH_DIR="" CACHE="${HOME}/.cache/afx-libtorch" OUT="" CHECKS=0 STRIP=0
while [[ $# -gt 0 ]]; do
  case "$1" in
    --torch) TORCH="${2:?--torch needs a version}"; shift 2 ;;
    --libtorch) LIBTORCH_DIR="${2:?--libtorch needs a directory}"; shift 2 ;;
    --cache) CACHE="${2:?--cache needs a directory}"; shift 2 ;;
    --out) OUT="${2:?--out needs a directory}"; shift 2 ;;
    --checks) CHECKS=1; shift ;;
    --strip) STRIP=1; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "build-gpu-torch.sh: unknown argument '$1'" >&2; usage >&2; exit 2 ;;
  esac
done
cd "$(dirname "$0")/.."
[[ -n "$OUT" ]] || OUT=target/gpu-torch
command -v cargo >/dev/null || { echo "build-gpu-torch.sh: cargo not found: install Rust from https://rustup.rs" >&2; exit 1; }

if [[ -z "$LIBTORCH_DIR" ]]; then
  LIBTORCH_DIR="$CACHE/$TORCH/torch"
  if [[ ! -f "$LIBTORCH_DIR/lib/libtorch_cpu.so" ]]; then
    echo "fetching PyTorch $TORCH's libtorch from PyPI into $CACHE/$TORCH ..."
    mkdir -p "$CACHE/$TORCH"
    python3 -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 \
      --implementation cp --platform manylinux_2_28_x86_64 -d "$CACHE/$TORCH" "torch==$TORCH" \
      || { echo "build-gpu-torch.sh: pip could not fetch torch==$TORCH (is python3 -m pip there, and PyPI reachable?)" >&2; exit 1; }
    wheel=$(ls "$CACHE/$TORCH"/torch-"$TORCH"-*.whl | head -n 1)
    (cd "$CACHE/$TORCH" && python3 -m zipfile -e "$wheel" unpacked && rm -rf torch && mv unpacked/torch torch && rm -rf unpacked "$wheel")
  fi
fi
LIBTORCH_DIR="$(cd "$LIBTORCH_DIR" && pwd)"
[[ -d "$LIBTORCH_DIR/include" && -d "$LIBTORCH_DIR/lib" ]] \
  || { echo "build-gpu-torch.sh: $LIBTORCH_DIR has no include/ and lib/: not a libtorch" >&2; exit 1; }
echo "building against $LIBTORCH_DIR"

# torch-sys 0.22 is written for PyTorch 2.9; its C wrapper compiles against 2.11.
export LIBTORCH="$LIBTORCH_DIR" LIBTORCH_BYPASS_VERSION_CHECK=1
targets=(-p learner -p actor --bins)
[[ $CHECKS -eq 0 ]] || targets+=(-p training -p nets -p gateway --bench learning --bench env_steps --bench unet_inference --bench ppo_batches --bench adam_steps --test gpu_matches_cpu)
mkdir -p "$OUT"
# Every executable cargo builds, with its target's name (a bench's or test's is hashed).
cargo build --release --features nets/gpu-torch,training/gpu-torch "${targets[@]}" --message-format=json-render-diagnostics \
  | python3 -c '
import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable"):
        print(m["target"]["name"], m["executable"])
' | while read -r name path; do
  cp "$path" "$OUT/$name"
  [[ $STRIP -eq 0 ]] || strip "$OUT/$name"
done
echo "binaries in $OUT: $(ls "$OUT" | tr '\n' ' ')"
echo "run them where python3's torch is PyTorch $TORCH (or set LD_LIBRARY_PATH to $LIBTORCH_DIR/lib's twin there)"
