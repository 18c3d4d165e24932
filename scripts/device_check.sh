#!/usr/bin/env bash
# The GPU workflow in one script (docs/gpu.md, "Developer: GPU workflow").
#
#   here:        bash scripts/device_check.sh pack  [BUILD_DIR] [CARRY_DIR]
#   GPU machine: bash scripts/device_check.sh run   [CARRY_DIR]
#
# `pack` builds zona for sm_90 in BUILD_DIR (default build-cuda) and copies the stripped test,
# benchmark and CLI binaries plus libcudart into CARRY_DIR (default build-device, a few MB:
# the device machine has no compiler guarantee and no network, so binaries travel).
# `run` executes on the GPU machine, writing to $OUT (default ./device-out): nvidia-smi,
# `zona info --json`, the GPU tests, compute-sanitizer memcheck and racecheck over them, the
# GPU benchmark, and a summary (printed last). Environment:
#   DEVICE_CHECK_STAGES  comma list of smi,tests,memcheck,racecheck,bench,scaling,interop,job,
#                        haptics,study (default: all but study)
#   JOB_SIZES            vertex counts of the job benchmark (default 1e3,1e4,1e5,1e6,4e6)
#   SCALING_MAX          largest size of the `zona bench --vertices sweep` stage (default 1.6e7)
#   TEST_FILTER          gtest filter of the GPU tests (default 'Cuda*')
#   SANITIZER_FILTER     gtest filter under compute-sanitizer (default: TEST_FILTER)
#   BENCH_SIZES          vertex counts for the benchmark (default 10000,100000,1000000)
#   BENCH_VARIANTS       benchmark variants (default all)
#   BENCH_ARGS           extra benchmark arguments (e.g. "--substeps 200 --repeats 9")
#   TESTS_TIMEOUT, BENCH_TIMEOUT, SANITIZER_TIMEOUT  seconds per stage (240, 300, 150)
#   INTEROP_SIZES        vertex counts of the interop benchmark (default 10000,100000,1000000)
# Stages run in the order smi, tests, bench, scaling, interop, memcheck, racecheck; each writes
# its log as it goes, so a call cut short still brings back what finished.
# The interop stage (CUDA-Vulkan, docs/rendering.md) needs a Vulkan loader: carry `.gl` (Debian's
# libvulkan1 and vulkan-validationlayers .deb files, unpacked there) when the machine has none;
# the NVIDIA ICD is taken from the driver's json.
set -uo pipefail
cd "$(dirname "$0")/.."
mode=${1:-}

pack() {
  local build=${1:-build-cuda} carry=${2:-build-device}
  local nvcc=nvcc
  command -v nvcc >/dev/null || nvcc=/usr/local/cuda/bin/nvcc
  set -e
  # The device machine has no libcholmod (Debian's SuiteSparse): the direct solver is left out.
  cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release -DZONA_BENCH=ON -DZONA_CHOLMOD=OFF \
    -DCMAKE_CUDA_COMPILER="$(command -v "$nvcc" || echo "$nvcc")" \
    -DCMAKE_CUDA_ARCHITECTURES=90 >/dev/null
  local targets=(zona_tests gpu_step_bench zona)
  # The renderer (and so interop_bench) exists when Vulkan headers and glslc were found.
  # (Not `| grep -q`: grep's early exit fails the pipeline under pipefail.)
  local help
  help=$(cmake --build "$build" --target help 2>/dev/null || true)
  if [[ "$help" == *interop_bench* ]]; then
    targets+=(interop_bench)
  fi
  cmake --build "$build" -j "${ZONA_JOBS:-2}" --target "${targets[@]}"
  rm -rf "$carry"
  mkdir -p "$carry"
  cp "$build/tests/zona_tests" "$build/bench/gpu_step_bench" "$build/apps/zona" "$carry/"
  [ -x "$build/bench/interop_bench" ] && cp "$build/bench/interop_bench" "$carry/"
  strip "$carry"/zona_tests "$carry"/gpu_step_bench "$carry"/zona
  [ -x "$carry/interop_bench" ] && strip "$carry/interop_bench"
  local cudart
  cudart=$(ldd "$carry/gpu_step_bench" | awk '/libcudart/ {print $3}')
  [ -n "$cudart" ] && cp -L "$cudart" "$carry/"
  du -sh "$carry"
  echo "carry $carry: run with  bash scripts/device_check.sh run $carry"
}

run() {
  local carry=${1:-build-device}
  local out=${OUT:-device-out}
  local stages=${DEVICE_CHECK_STAGES:-smi,tests,memcheck,racecheck,bench,scaling,interop,job,haptics}
  local filter=${TEST_FILTER:-Cuda*}
  mkdir -p "$out"
  export LD_LIBRARY_PATH="$PWD/$carry${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
  local sanitizer
  sanitizer=$(command -v compute-sanitizer || echo /usr/local/cuda/bin/compute-sanitizer)
  local summary="$out/summary.txt"
  : >"$summary"
  note() { echo "$*" | tee -a "$summary"; }
  has() { [[ ",$stages," == *",$1,"* ]]; }

  if has smi; then
    { nvidia-smi; nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.mem \
        --format=csv; "$carry/zona" info --json; } >"$out/nvidia-smi.txt" 2>&1
    note "device: $(nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>&1)"
  fi
  if has tests; then
    timeout "${TESTS_TIMEOUT:-240}" "$carry/zona_tests" --gtest_filter="$filter" \
      >"$out/tests.log" 2>&1
    note "tests ($filter): rc $? ; $(grep -E '^\[  (PASSED|FAILED|SKIPPED) ' "$out/tests.log" |
      tr '\n' ' ')"
    grep -E '^\[  FAILED  \]' "$out/tests.log" | sort -u | tee -a "$summary"
  fi
  if has bench; then
    # shellcheck disable=SC2086
    timeout "${BENCH_TIMEOUT:-300}" "$carry/gpu_step_bench" \
      --sizes "${BENCH_SIZES:-10000,100000,1000000}" --variants "${BENCH_VARIANTS:-all}" \
      --out "$out/bench.csv" ${BENCH_ARGS:-} >"$out/bench.log" 2>&1
    note "bench: rc $?"
    sed -n '/^# /p;/^vertices /,$p' "$out/bench.log" | tee -a "$summary"
  fi
  if has scaling; then
    # The vertices-versus-time benchmark (bench/README.md): Ladjal et al. Table II's sizes on the GPU
    # and on this host's CPU, then the GPU sweep in powers of two.
    local day
    day=$(date -u +%Y-%m-%d)
    timeout "${SCALING_TIMEOUT:-300}" "$carry/zona" bench --backend all --model svk \
      --vertices table2 --out "$out/scaling_table2_$day.csv" >"$out/scaling.log" 2>&1
    note "zona bench table2: rc $?"
    timeout "${SCALING_TIMEOUT:-300}" "$carry/zona" bench --backend cuda --model svk \
      --vertices sweep --max-vertices "${SCALING_MAX:-1.6e7}" \
      --out "$out/scaling_sweep_$day.csv" >>"$out/scaling.log" 2>&1
    note "zona bench sweep: rc $?"
  fi
  if has interop; then
    # CUDA-Vulkan interop: the GPU-vs-copy-path tests, the benchmark, a validated frame.
    if [ -d .gl ] && ! ldconfig -p | grep -q libvulkan.so.1; then
      for f in .gl/*.deb; do dpkg -x "$f" /; done
      ldconfig
    fi
    local icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    [ -e "$icd" ] && export VK_DRIVER_FILES=$icd
    export ZONA_VK_DEVICE=NVIDIA
    timeout "${TESTS_TIMEOUT:-240}" "$carry/zona_tests" --gtest_filter='CudaInterop*:Renderer*' \
      >"$out/interop_tests.log" 2>&1
    note "interop tests: rc $? ; $(grep -E '^\[  (PASSED|FAILED|SKIPPED) ' \
      "$out/interop_tests.log" | tr '\n' ' ')"
    grep -E '^\[  FAILED  \]' "$out/interop_tests.log" | sort -u | tee -a "$summary"
    if [ -x "$carry/interop_bench" ]; then
      timeout "${BENCH_TIMEOUT:-300}" "$carry/interop_bench" \
        --vertices "${INTEROP_SIZES:-10000,100000,1000000}" \
        --out "$out/interop_$(date -u +%Y-%m-%d).csv" >"$out/interop_bench.log" 2>&1
      note "interop bench: rc $?"
      tee -a "$summary" <"$out/interop_bench.log"
    fi
    timeout 200 "$carry/zona" render mouse_oocyte --backend cuda --validate \
      --set needle.speed=1mm/s --time 25ms --out "$out/interop_frame.png" \
      >"$out/interop_render.log" 2>&1
    note "zona render --backend cuda (interop): rc $? ; $(tail -2 "$out/interop_render.log" | tr '\n' ' ')"
  fi
  if has job; then
    # The injection job (zona bench --job, docs/gpu.md) at JOB_SIZES, then the 1M-vertex mouse
    # injection to puncture as a user runs it, wall time including setup.
    local day
    day=$(date -u +%Y-%m-%d)
    timeout "${JOB_TIMEOUT:-400}" "$carry/zona" bench --job --backend cuda \
      --vertices "${JOB_SIZES:-1e3,1e4,1e5,1e6,4e6}" --repeats 5 \
      --max-run-seconds "${JOB_RUN_SECONDS:-40}" --out "$out/job_$day.csv" >"$out/job.log" 2>&1
    note "job bench: rc $?"
    grep -E "vertices:" "$out/job.log" | tee -a "$summary"
    /usr/bin/time -f "wall %e s" timeout 120 "$carry/zona" run --backend cuda --quiet \
      --no-frames --stop-after-puncture 0 --set mesh.generate.vertices=1000000 \
      --out "$out/run_1m" >"$out/run_1m.log" 2>&1
    note "zona run 1M vertices: rc $? ; $(grep -E 'puncture|wall|error' "$out/run_1m.log" | tr '\n' ' ')"
  fi
  if has haptics; then
    # The haptic loop on the fine scene, fed from the device (16 cores: the loop's own rate).
    timeout 60 "$carry/zona" haptics mouse_oocyte_fine --backend cuda --device scripted \
      --duration "${HAPTICS_SECONDS:-15}" --json >"$out/haptics_fine.json" 2>"$out/haptics.log"
    note "haptics fine scene: rc $? ; $(grep -E '"(rate_hz|period_p99_us|sim_real_time_ratio|puncture_felt_delay_ms|punctured)"' \
      "$out/haptics_fine.json" | tr -d ' \n')"
  fi
  if has study; then
    # The convergence study (docs/validation.md) on the GPU, neo-Hookean, STUDY_SIZES.
    timeout "${STUDY_TIMEOUT:-420}" "$carry/zona" study convergence mouse_oocyte --backend cuda \
      --vertices "${STUDY_SIZES:-4e3,16e3,64e3,256e3,1e6}" --set model=neohookean ${STUDY_ARGS:-} \
      --out "$out/study" >"$out/study.log" 2>&1
    note "study: rc $? ; $(tail -3 "$out/study.log" | tr '\n' ' ')"
  fi
  local sfilter=${SANITIZER_FILTER:-$filter}
  if has memcheck; then
    timeout "${SANITIZER_TIMEOUT:-150}" "$sanitizer" --tool memcheck --leak-check full \
      --error-exitcode 9 "$carry/zona_tests" --gtest_filter="$sfilter" >"$out/memcheck.log" 2>&1
    note "memcheck ($sfilter): rc $? ; $(grep -E 'ERROR SUMMARY' "$out/memcheck.log" | tail -1)"
  fi
  if has racecheck; then
    timeout "${SANITIZER_TIMEOUT:-150}" "$sanitizer" --tool racecheck --error-exitcode 9 \
      "$carry/zona_tests" --gtest_filter="$sfilter" >"$out/racecheck.log" 2>&1
    note "racecheck ($sfilter): rc $? ; $(grep -E 'RACECHECK SUMMARY|ERROR SUMMARY' \
      "$out/racecheck.log" | tail -1)"
  fi
}

case "$mode" in
  pack) shift; pack "$@" ;;
  run) shift; run "$@" ;;
  *) echo "usage: $0 pack [BUILD_DIR] [CARRY_DIR] | run [CARRY_DIR]" >&2; exit 2 ;;
esac
