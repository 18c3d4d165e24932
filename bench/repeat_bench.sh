#!/usr/bin/env bash
# Runs one `zona bench` command N times, PAUSE seconds apart, and writes every run's rows into one
# CSV with two leading columns: the run's index and the host's steal time during it (percent of
# CPU time, from the comment line `zona bench` ends its CSV with). On a shared VM whose speed
# drifts by tens of per cent within minutes (bench/README.md), one run is one sample; this gives
# the spread. Prints the median and range of step_ms_median per (backend, threads, vertices).
#
#   bench/repeat_bench.sh ZONA N PAUSE OUT.csv [zona bench arguments...]
#   bench/repeat_bench.sh build/apps/zona 12 30 bench/results/cpu_step1101_repeats_$D.csv \
#       --backend cpu --vertices 1093 --threads 1,2 --steps 2000 --repeats 9
set -euo pipefail
if [ $# -lt 4 ]; then
  sed -n '2,10p' "$0" >&2
  exit 2
fi
zona=$1 runs=$2 pause=$3 out=$4
shift 4
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
: > "$out.rows"
for ((i = 1; i <= runs; i++)); do
  "$zona" bench "$@" --out "$tmp/run.csv" > /dev/null 2>&1
  steal=$(sed -n 's/^# host steal time during the run: \([0-9.]*\) %.*/\1/p' "$tmp/run.csv")
  if [ "$i" = 1 ]; then
    {
      grep '^#' "$tmp/run.csv" | grep -v '^# host steal'
      echo "# repeat_bench.sh: $runs runs, $pause s apart, started $(date -u +%H:%M) UTC; leading columns: run, host_steal_pct"
      grep -v '^#' "$tmp/run.csv" | head -1 | sed 's/^/run,host_steal_pct,/'
    } > "$out"
  fi
  grep -v '^#' "$tmp/run.csv" | tail -n +2 | sed "s/^/$i,${steal:-nan},/" >> "$out.rows"
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
