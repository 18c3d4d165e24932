#!/usr/bin/env bash
# The haptic loop's rate on a given set of cores (issue 7's target: 1000 Hz +- 0.5 %, p99 period
# <= 1.25 ms, with the mouse scene simulating on the same two cores). Runs `zona haptics SCENE
# --device emulated --duration D --json` RUNS times per scene, pinned with taskset, and prints
# one JSON line per run plus the host's steal time over the run (/proc/stat, jiffies):
#
#   bash scripts/haptics_rate.sh ZONA_BINARY [CORES] [RUNS] [DURATION] [SCENES...]
#   e.g. bash scripts/haptics_rate.sh build/apps/zona 2,3 3 10 mouse_oocyte mouse_oocyte_haptic
set -uo pipefail
zona=${1:?zona binary}
cores=${2:-0,1}
runs=${3:-3}
duration=${4:-10}
shift $(( $# < 4 ? $# : 4 ))
scenes=("$@")
[ ${#scenes[@]} -eq 0 ] && scenes=(mouse_oocyte mouse_oocyte_haptic)
steal() { awk '/^cpu /{print $9}' /proc/stat; }
echo "# $(date -u +%FT%TZ) $(uname -r) cores $cores of $(nproc): $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)"
for scene in "${scenes[@]}"; do
  for ((i = 1; i <= runs; ++i)); do
    s0=$(steal)
    json=$(taskset -c "$cores" "$zona" haptics "$scene" --device emulated --duration "$duration" \
      --json 2>/dev/null | tr -d "\n ")
    s1=$(steal)
    echo "{\"scene\":\"$scene\",\"run\":$i,\"steal_jiffies\":$((s1 - s0)),\"result\":${json:-null}}"
  done
done
