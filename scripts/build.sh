#!/usr/bin/env bash
# Configures and builds zona in ./build (or $ZONA_BUILD_DIR). CUDA is used when nvcc is found.
# Extra arguments go to cmake's configure step, e.g. -DZONA_SANITIZE=address.
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${ZONA_BUILD_DIR:-build}
jobs=${ZONA_JOBS:-$(nproc)}
if ! command -v nvcc >/dev/null && [ -x /usr/local/cuda/bin/nvcc ]; then
  export PATH=/usr/local/cuda/bin:$PATH
fi
cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=${ZONA_BUILD_TYPE:-Release} "$@" >/dev/null
cmake --build "$build_dir" -j "$jobs"
