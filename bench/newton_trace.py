#!/usr/bin/env python3
"""Summarise a static run's Newton trace (ZONA_NEWTON_TRACE=1 zona run ... --solver static 2> T).

Prints the solves (converged / failed) with their Newton iterations, CG iterations and wall
time per Newton iteration (median / largest), the CG iterations at the fixed tolerance of
ZONA_KRYLOV_PROBE where the trace has them, the line search's steps (how far below the capped
step it backtracked: 2^-k), the vertices where the residual sat in the iterations that
backtracked, and, with --solves, every solve's travel and outcome.

    python3 bench/newton_trace.py T [--solves]
    python3 bench/newton_trace.py T --row LABEL   # one CSV row (header with --header)

The row: label, Newton iterations traced, CG per Newton iteration (median, largest), ms per
Newton iteration (median), CG at the probe's tolerance (median, largest; empty without it).
"""
import collections
import math
import sys


def main():
    if len(sys.argv) < 2:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    solves = []
    for line in open(sys.argv[1]):
        f = line.split()
        if not f:
            continue
        if f[0] == "solve":
            solves.append({"travel": float(f[2]), "its": [], "end": None})
        elif f[0] == "newton" and f[1] == "iteration" and solves:
            solves[-1]["its"].append(dict(zip(f[3::2], f[4::2])))
        elif f[0] == "newton" and f[1] == "end" and solves:
            solves[-1]["end"] = f[2]
    its = [it for s in solves for it in s["its"]]

    def spread(key, cast=float):
        v = sorted(cast(it[key]) for it in its if key in it and cast(it[key]) >= 0)
        return (v[len(v) // 2], v[-1], sum(v)) if v else None

    if "--row" in sys.argv:
        label = sys.argv[sys.argv.index("--row") + 1]
        cg, ms, probe = spread("cg"), spread("ms"), spread("probe_cg")
        if "--header" in sys.argv:
            print("label,newton_iterations,cg_median,cg_max,ms_median,probe_cg_median,probe_cg_max")
        print(f"{label},{len(its)},{cg[0]:g},{cg[1]:g},{ms[0]:g}," +
              (f"{probe[0]:g},{probe[1]:g}" if probe else ","))
        return 0
    ok = [s for s in solves if s["end"] == "converged"]
    bad = [s for s in solves if s["end"] == "failed"]
    count = lambda ss: sum(len(s["its"]) for s in ss)
    print(f"solves {len(solves)}: converged {len(ok)} ({count(ok)} Newton iterations), "
          f"failed {len(bad)} ({count(bad)})")
    for key, what in (("cg", "CG per Newton iteration"), ("ms", "ms per Newton iteration"),
                      ("probe_cg", "CG at the probe's tolerance")):
        m = spread(key)
        if m:
            print(f"{what}: median {m[0]:g}, largest {m[1]:g}, total {m[2]:g}")
    steps = collections.Counter()
    where = collections.Counter()
    for s in solves:
        for it in s["its"]:
            a = float(it["step"])
            k = round(-math.log2(a)) if a > 0 else 99
            steps[k] += 1
            if k > 0:
                where[it["at_vertex"]] += 1
    print("line search steps 2^-k (k: iterations):",
          ", ".join(f"{k}: {n}" for k, n in sorted(steps.items())))
    print("residual's vertex in backtracked iterations (vertex: iterations):",
          ", ".join(f"{v}: {n}" for v, n in where.most_common(12)))
    if "--solves" in sys.argv:
        for s in solves:
            print(f"  travel {s['travel']:.4f} um  {s['end']}  {len(s['its'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
