#!/usr/bin/env bash
# Configures and builds zona in ./build (or $ZONA_BUILD_DIR). CUDA is used when nvcc is found.
# Extra arguments go to cmake's configure step, e.g. -DZONA_SANITIZE=address. The Python module
# is built with the project's .venv (scripts/setup.sh), which then imports it from this build:
# a .pth file in the venv's site-packages names <build>/python.
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${ZONA_BUILD_DIR:-build}
jobs=${ZONA_JOBS:-$(nproc)}
if ! command -v nvcc >/dev/null && [ -x /usr/local/cuda/bin/nvcc ]; then
  export PATH=/usr/local/cuda/bin:$PATH
fi
python_args=()
if [ -x .venv/bin/python ]; then
  python_args=(-DPython_EXECUTABLE="$PWD/.venv/bin/python")
fi
cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=${ZONA_BUILD_TYPE:-Release} "${python_args[@]}" "$@" >/dev/null
cmake --build "$build_dir" -j "$jobs"
if [ -d "$build_dir/python/zona" ] && [ -x .venv/bin/python ]; then
  site=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
  (cd "$build_dir/python" && pwd) >"$site/zona-build.pth"
fi
