#!/usr/bin/env bash
# Runs one `zona bench` command N times, PAUSE seconds apart, and writes every run's rows into one
# CSV with two leading columns: the run's index and the host's steal time during it (percent of
# CPU time, from the comment line `zona bench` ends its CSV with). On a shared VM whose speed
# drifts by tens of per cent within minutes (bench/README.md), one run is one sample; this gives
# the spread. Prints the median and range of step_ms_median per (backend, threads, vertices).
#
#   bench/repeat_bench.sh ZONA N PAUSE OUT.csv [zona bench arguments...]
#   bench/repeat_bench.sh build/apps/zona 12 30 bench/results/cpu-xeon-2c/step1101_repeats.csv \
#       --backend cpu --vertices 1093 --threads 1,2 --steps 2000 --repeats 9
# With VCPU_PROBE=path/to/vcpu_pair_bench, two more leading columns: what a second thread added
# to one thread's vector arithmetic just before and just after each run (~2: two cores; ~1: the
# two vCPUs shared one core), so that a slow run can be told from a slow machine.
set -euo pipefail
if [ $# -lt 4 ]; then
  sed -n '2,13p' "$0" >&2
  exit 2
fi
zona=$1 runs=$2 pause=$3 out=$4
shift 4
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
: > "$out.rows"
probe_cols="" probe_vals=""
# Mean pair_scaling (last column) of two probe rounds.
probe() { "$VCPU_PROBE" --iterations 20000000 --rounds 2 | awk '{s += $4} END {printf "%.3f", s / NR}'; }
for ((i = 1; i <= runs; i++)); do
  if [ -n "${VCPU_PROBE:-}" ]; then before=$(probe); fi
  "$zona" bench "$@" --out "$tmp/run.csv" > /dev/null 2>&1
  if [ -n "${VCPU_PROBE:-}" ]; then
    probe_cols="vcpu_pair_before,vcpu_pair_after," probe_vals="$before,$(probe),"
  fi
  steal=$(sed -n 's/^# host steal time during the run: \([0-9.]*\) %.*/\1/p' "$tmp/run.csv")
  if [ "$i" = 1 ]; then
    {
      grep '^#' "$tmp/run.csv" | grep -v '^# host steal'
      echo "# repeat_bench.sh: $runs runs, $pause s apart, started $(date -u +%H:%M) UTC; leading columns: run, host_steal_pct${probe_cols:+, vcpu_pair_before, vcpu_pair_after}"
      grep -v '^#' "$tmp/run.csv" | head -1 | sed "s/^/run,host_steal_pct,$probe_cols/"
    } > "$out"
  fi
  grep -v '^#' "$tmp/run.csv" | tail -n +2 | sed "s/^/$i,${steal:-nan},$probe_vals/" >> "$out.rows"
  echo "run $i/$runs done (steal ${steal:-?} %)" >&2
  if [ "$i" -lt "$runs" ]; then sleep "$pause"; fi
done
cat "$out.rows" >> "$out"
rm -f "$out.rows"
echo "# finished $(date -u +%H:%M) UTC" >> "$out"
# Median and range of step_ms_median per (backend, threads, vertices).
awk -F, '
  NR == 1 || /^#/ { next }
  $1 == "run" { for (c = 1; c <= NF; c++) col[$c] = c; next }
  { key = $col["backend"] " " $col["threads"] " threads, " $col["vertices"] " vertices";
    n[key]++; v[key, n[key]] = $col["step_ms_median"] }
  END {
    for (k in n) {
      m = n[k]; for (i = 1; i <= m; i++) a[i] = v[k, i];
      for (i = 1; i <= m; i++) for (j = i + 1; j <= m; j++) if (a[j] < a[i]) { t = a[i]; a[i] = a[j]; a[j] = t }
      med = (m % 2) ? a[(m + 1) / 2] : (a[m / 2] + a[m / 2 + 1]) / 2;
      printf "%s: step_ms_median over %d runs: median %.4g, min %.4g, max %.4g\n", k, m, med, a[1], a[m]
    }
  }' "$out"
