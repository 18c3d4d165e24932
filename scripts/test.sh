#!/usr/bin/env bash
# Builds zona and runs the whole test suite with CTest (GPU tests skip without a device).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
ctest --test-dir "${ZONA_BUILD_DIR:-build}" --output-on-failure -j "${ZONA_JOBS:-$(nproc)}"
