#!/usr/bin/env bash
# The static solver's job benchmark: `zona run SCENE --solver static` for each case, the cases
# side by side (one process each), every run stopped with SIGINT after LIMIT seconds (it then
# writes what it has, and the row says "interrupted"). One CSV row per case: wall time, load
# steps, Newton and CG iterations (CG per Newton iteration: mean and the largest row's), the
# largest residual, the force at 10 / 20 / 30 / 40 um of deformation (linear between rows;
# the rows at those deformations are exact, docs/static.md), and every solve's Newton and CG
# iterations with the failed solves (summary.json; the row columns count accepted steps only).
#
#   bench/static_runs.sh ZONA OUT_DIR LIMIT CASE...
#   CASE = name:scene:vertices:preconditioner[:key=value,key=value...]
#   bench/static_runs.sh build/apps/zona /tmp/st 600 \
#       6k-jacobi:mouse_oocyte:6000:jacobi 64k-mg:mouse_oocyte_fine:64000:multigrid:puncture.criterion=none,needle.max_travel=42um
# Writes OUT_DIR/static_runs.csv and each run's folder OUT_DIR/<name>/ (force.csv, summary.json,
# log.txt).
set -euo pipefail
if [ $# -lt 4 ]; then
  sed -n '2,14p' "$0" >&2
  exit 2
fi
zona=$1 out=$2 limit=$3
shift 3
mkdir -p "$out"
pids=()
for spec in "$@"; do
  IFS=: read -r name scene vertices precond extra <<< "$spec"
  sets=(--set "mesh.generate.vertices=$vertices" --set "solver.preconditioner=$precond"
        --set "output.frames=0")
  if [ -n "${extra:-}" ]; then
    IFS=, read -r -a kv <<< "$extra"
    for s in "${kv[@]}"; do sets+=(--set "$s"); done
  fi
  mkdir -p "$out/$name"
  (
    start=$(date +%s.%N)
    rc=0
    timeout -s INT "$limit" "$zona" run "$scene" --solver static "${sets[@]}" --out "$out/$name" \
      > "$out/$name/log.txt" 2>&1 || rc=$?
    end=$(date +%s.%N)
    echo "$rc $(awk -v a="$start" -v b="$end" 'BEGIN { printf "%.2f", b - a }')" > "$out/$name/wall.txt"
  ) &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p" || true; done

csv="$out/static_runs.csv"
echo "case,vertices,preconditioner,exit,wall_s,rows,newton,cg,cg_per_newton,cg_per_newton_max,residual_max_N,F10_uN,F20_uN,F30_uN,F40_uN,newton_all,cg_all,failed_solves" > "$csv"
for spec in "$@"; do
  IFS=: read -r name scene vertices precond extra <<< "$spec"
  read -r rc wall < "$out/$name/wall.txt"
  f="$out/$name/force.csv"
  if [ ! -s "$f" ]; then
    echo "$name,$vertices,$precond,$rc,$wall,0,,,,,,,,,,,," >> "$csv"
    continue
  fi
  # Columns by name (schema 4 and later): deformation_m, force_N, newton_iterations, krylov_iterations,
  # residual_N.
  # Every solve of the run (summary.json numerics.static: the failed ones included).
  all=",,"
  if [ -s "$out/$name/summary.json" ]; then
    n_all=$(grep -o '"newton_iterations": [0-9]*' "$out/$name/summary.json" | grep -o '[0-9]*$' || true)
    k_all=$(grep -o '"krylov_iterations": [0-9]*' "$out/$name/summary.json" | grep -o '[0-9]*$' || true)
    f_all=$(grep -o '"failed_solves": [0-9]*' "$out/$name/summary.json" | grep -o '[0-9]*$' || true)
    all="$n_all,$k_all,$f_all"
  fi
  awk -F, -v name="$name" -v v="$vertices" -v p="$precond" -v rc="$rc" -v wall="$wall" -v all="$all" '
    /^#/ { next }
    !hdr { for (i = 1; i <= NF; i++) col[$i] = i; hdr = 1; next }
    {
      d = $col["deformation_m"] * 1e6; F = $col["force_N"] * 1e6
      n = $col["newton_iterations"]; k = $col["krylov_iterations"]; r = $col["residual_N"]
      rows++; newton += n; cg += k
      if (n > 0 && k / n > kmax) kmax = k / n
      if (r > rmax) rmax = r
      for (t = 10; t <= 40; t += 10)
        if (!(t in at) && rows > 1 && pd <= t && d >= t)
          at[t] = (d > pd) ? pF + (F - pF) * (t - pd) / (d - pd) : F
      pd = d; pF = F
    }
    END {
      printf "%s,%s,%s,%s,%.1f,%d,%d,%d,%.1f,%.1f,%.3g", name, v, p, rc, wall, rows, newton, cg,
             (newton > 0 ? cg / newton : 0), kmax, rmax
      for (t = 10; t <= 40; t += 10) printf ",%s", ((t in at) ? sprintf("%.4f", at[t]) : "")
      printf ",%s\n", all
    }' "$f" >> "$csv"
done
cat "$csv"
