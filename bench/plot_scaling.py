#!/usr/bin/env python3
"""Plot of `zona bench` CSVs: step time and precompute time versus vertices (log-log), each
series (backend, model, formulation, threads), Ladjal et al. Table II's points, fitted power laws
with their exponents in the legend and on stdout, the haptic (1 kHz) and visual (30 Hz) budgets
and, when CPU and GPU rows are both given, the crossover size.

    .venv/bin/python bench/plot_scaling.py bench/results/cpu-xeon-2c/sweep.csv [bench/results/h100/sweep.csv ...] --out plot.png

Needs matplotlib: scripts/setup.sh installs it from PyPI into the project environment .venv.
"""

import argparse
import csv
import math
import sys
from collections import OrderedDict

# Ladjal et al. Table II (SVK mass tensors, Intel Core Duo 3.2 GHz, 2009): vertices, tetrahedra,
# precompute [ms], step [ms]. The same numbers as bench/scaling/scaling_bench.cpp's kSeedTable2.
SEED_TABLE2 = [
    (115, 332, 0.875, 0.047), (123, 379, 0.99, 0.047), (128, 407, 1.094, 0.063),
    (165, 546, 1.718, 0.078), (176, 614, 2.031, 0.094), (192, 672, 2.359, 0.109),
    (271, 979, 4.546, 0.156), (282, 1019, 4.859, 0.156), (346, 1269, 7.39, 0.187),
    (516, 2130, 18.828, 0.328), (731, 3060, 36.5, 0.453), (1093, 4819, 88.734, 0.703),
]

HAPTIC_MS = 1.0          # 1 kHz
VISUAL_MS = 1000.0 / 30  # 30 Hz


def read_rows(paths):
    """Rows of every CSV (comment lines skipped), with numbers converted."""
    rows = []
    for spec in paths:
        # FILE:BACKEND keeps only that backend's rows of FILE (e.g. the GPU rows of a run made on
        # another machine, whose CPU rows belong to that machine's CPU).
        path, only = spec, None
        if ":" in spec and spec.rsplit(":", 1)[1] in ("cpu", "cuda"):
            path, only = spec.rsplit(":", 1)
        with open(path, newline="") as f:
            lines = [line for line in f if not line.startswith("#") and line.strip()]
        # Several runs may be concatenated in one file: later copies of the header are skipped.
        header = lines[0] if lines else ""
        lines = lines[:1] + [line for line in lines[1:] if line != header]
        for r in csv.DictReader(lines):
            if only and r["backend"] != only:
                continue
            for key in ("vertices", "tets", "threads", "target_vertices"):
                r[key] = int(r[key])
            # threads_requested 0: the backend's automatic count (one series, "auto").
            r["thread_key"] = (int(r["threads"]) if int(r.get("threads_requested", 1) or 1) > 0
                               else "auto")
            for key in ("precompute_ms", "step_ms_median", "step_ms_p90", "floor_ms"):
                r[key] = float(r[key])
            rows.append(r)
    return rows


def fit_power_law(xs, ys):
    """Least-squares fit of log y = log a + b log x; returns (a, b) or None."""
    pts = [(math.log(x), math.log(y)) for x, y in zip(xs, ys) if x > 0 and y > 0]
    if len(pts) < 2:
        return None
    n = len(pts)
    mx = sum(p[0] for p in pts) / n
    my = sum(p[1] for p in pts) / n
    sxx = sum((p[0] - mx) ** 2 for p in pts)
    if sxx == 0:
        return None
    b = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx
    return math.exp(my - b * mx), b


def series_of(rows, filters):
    """Series keyed by (backend, model, formulation, threads): sorted (vertices, row) lists."""
    out = OrderedDict()
    for r in rows:
        if any(v and r[k] not in v for k, v in filters.items()):
            continue
        if r["step_ms_median"] <= 0:
            continue
        key = (r["backend"], r["model"], r["formulation"], r["thread_key"])
        out.setdefault(key, []).append(r)
    for key in out:
        # One point per mesh size (a repeated size keeps its last measurement).
        by_size = OrderedDict()
        for r in out[key]:
            by_size[r["vertices"]] = r
        out[key] = sorted(by_size.values(), key=lambda r: r["vertices"])
    return out


def label_of(key):
    backend, model, form, threads = key
    if backend != "cpu":
        return f"{backend} {model} {form}"
    return f"{backend} {model} {form} " + (f"{threads}t" if threads != "auto" else "auto")


def budget_size(fit, budget_ms):
    """Vertices at which the fitted step time reaches the budget."""
    if not fit or fit[1] <= 0:
        return None
    a, b = fit
    return (budget_ms / a) ** (1.0 / b)


def print_table2(rows, series):
    """Markdown: the seed's twelve rows beside each series' rows of the same target size."""
    seed = {r[0]: r for r in SEED_TABLE2}
    keys = [k for k in series if any(r["target_vertices"] in seed for r in series[k])]
    if not keys:
        return
    print()
    head = "| seed vertices / tets | seed precompute ms | seed step ms |"
    rule = "|---|---|---|"
    for k in keys:
        head += f" {label_of(k)}: vertices / tets, precompute ms, step ms |"
        rule += "---|"
    print(head)
    print(rule)
    for n, (sv, st, sp, ss) in seed.items():
        line = f"| {sv} / {st} | {sp:g} | {ss:g} |"
        for k in keys:
            match = [r for r in rows if r["target_vertices"] == n and
                     (r["backend"], r["model"], r["formulation"], r["thread_key"]) == k]
            if match:
                r = match[-1]
                line += (f" {r['vertices']} / {r['tets']}, {r['precompute_ms']:.3g}, "
                         f"{r['step_ms_median']:.3g} |")
            else:
                line += " - |"
        print(line)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("csv", nargs="+",
                   help="zona bench CSV file(s); FILE:cpu or FILE:cuda keeps one backend's rows")
    p.add_argument("--out", help="PNG to write (default: the first CSV with .png)")
    p.add_argument("--model", action="append", help="only this model (repeatable)")
    p.add_argument("--formulation", action="append", help="only this formulation (repeatable)")
    p.add_argument("--backend", action="append", help="only this backend (repeatable)")
    p.add_argument("--threads", action="append", type=int,
                   help="only this CPU thread count (as run)")
    p.add_argument("--series", action="append",
                   help="only this series, by its label, e.g. 'cpu svk gradient 2t' (repeatable)")
    p.add_argument("--fit-min", type=float, default=1000,
                   help="fit step times from this many vertices on (default 1000)")
    p.add_argument("--fit-max", type=float, default=float("inf"), help="... up to this many")
    p.add_argument("--title", default="zona: time versus mesh size")
    p.add_argument("--table2", action="store_true",
                   help="also print, as Markdown, each series at the seed's Table II sizes "
                        "beside the seed's numbers")
    args = p.parse_args()

    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        sys.exit("plot_scaling.py: matplotlib is missing: install python3-matplotlib "
                 "(scripts/setup.sh) or run with /usr/bin/python3")

    rows = read_rows(args.csv)
    filters = {"model": args.model, "formulation": args.formulation, "backend": args.backend,
               "threads": args.threads}
    series = series_of(rows, filters)
    if args.series:
        series = OrderedDict((k, v) for k, v in series.items() if label_of(k) in args.series)
    if not series:
        sys.exit("plot_scaling.py: no rows to plot")

    fig, (ax_step, ax_pre) = plt.subplots(1, 2, figsize=(14, 6))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fits = OrderedDict()
    print(f"{'series':36s} {'step exponent':>14s} {'fit range':>20s} {'precompute exp.':>16s}"
          f" {'haptic 1 ms':>12s} {'visual 30 Hz':>13s}")
    for i, (key, pts) in enumerate(series.items()):
        color = colors[i % len(colors)]
        marker = "o" if key[0] == "cpu" else "s"
        xs = [r["vertices"] for r in pts]
        step = [r["step_ms_median"] for r in pts]
        p90 = [r["step_ms_p90"] for r in pts]
        pre = [r["precompute_ms"] for r in pts]
        in_fit = [(x, y) for x, y in zip(xs, step) if args.fit_min <= x <= args.fit_max]
        fit = fit_power_law([q[0] for q in in_fit], [q[1] for q in in_fit])
        fit_pre = fit_power_law(xs, pre)
        fits[key] = fit
        label = label_of(key)
        step_label = label + (f"  (n^{fit[1]:.2f})" if fit else "")
        ax_step.errorbar(xs, step, yerr=[[0] * len(xs), [b - a for a, b in zip(step, p90)]],
                         fmt=marker, ms=4, color=color, label=step_label, capsize=2)
        if fit:
            lo, hi = min(q[0] for q in in_fit), max(q[0] for q in in_fit)
            grid = [lo * (hi / lo) ** (k / 40) for k in range(41)]
            ax_step.plot(grid, [fit[0] * g ** fit[1] for g in grid], "-", color=color, lw=1)
        ax_pre.plot(xs, pre, marker, ms=4, color=color,
                    label=label + (f"  (n^{fit_pre[1]:.2f})" if fit_pre else ""))
        if fit_pre:
            ax_pre.plot(xs, [fit_pre[0] * x ** fit_pre[1] for x in xs], "-", color=color, lw=1)
        # Largest mesh per budget: measured (largest size within budget) and from the fit.
        def within(budget):
            ok = [x for x, y in zip(xs, step) if y <= budget]
            fitted = budget_size(fit, budget)
            measured = f"{max(ok):,}" if ok else "-"
            return measured + (f" (fit {fitted:.3g})" if fitted else "")
        fit_range = (f"{min(q[0] for q in in_fit):.0f}..{max(q[0] for q in in_fit):.0f}"
                     if in_fit else "-")
        print(f"{label:36s} {fit[1] if fit else float('nan'):14.3f} {fit_range:>20s} "
              f"{fit_pre[1] if fit_pre else float('nan'):16.3f} {within(HAPTIC_MS):>12s} "
              f"{within(VISUAL_MS):>13s}")

    # Ladjal et al. Table II and its own power laws.
    sx = [r[0] for r in SEED_TABLE2]
    s_step = [r[3] for r in SEED_TABLE2]
    s_pre = [r[2] for r in SEED_TABLE2]
    f_step, f_pre = fit_power_law(sx, s_step), fit_power_law(sx, s_pre)
    ax_step.plot(sx, s_step, "k^", ms=6, mfc="none",
                 label=f"Ladjal et al. Table II (n^{f_step[1]:.2f})")
    ax_pre.plot(sx, s_pre, "k^", ms=6, mfc="none", label=f"Ladjal et al. Table II (n^{f_pre[1]:.2f})")
    print(f"{'Ladjal et al. Table II':36s} {f_step[1]:14.3f} {'115..1093':>20s} {f_pre[1]:16.3f}")

    # GPU-over-CPU crossover per model and formulation, from the sizes both measured.
    for key, pts in series.items():
        if key[0] != "cuda":
            continue
        for ckey, cpts in series.items():
            if ckey[0] != "cpu" or ckey[1:3] != key[1:3]:
                continue
            cpu_at = {r["target_vertices"]: r["step_ms_median"] for r in cpts}
            both = sorted((r["target_vertices"], r["step_ms_median"], cpu_at[r["target_vertices"]])
                          for r in pts if r["target_vertices"] in cpu_at)
            if not both:
                continue
            faster = [n for n, g, c in both if g < c]
            if not faster:
                verdict = f"the CPU is faster at every common size ({both[0][0]}..{both[-1][0]})"
            elif len(faster) == len(both):
                verdict = (f"the GPU is faster at every common size, from the smallest "
                           f"({both[0][0]}, {both[0][2] / both[0][1]:.1f}x) to the largest "
                           f"({both[-1][0]}, {both[-1][2] / both[-1][1]:.1f}x)")
            else:
                verdict = f"the GPU is faster from about {faster[0]} vertices on"
            print(f"crossover {label_of(key)} vs {label_of(ckey)}: {verdict}")

    if args.table2:
        print_table2(rows, series)

    for ax, what in ((ax_step, "step time [ms]"), (ax_pre, "precompute time [ms]")):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("vertices")
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
    right = ax_step.get_xlim()[1] / 1.15
    ax_step.axhline(HAPTIC_MS, color="grey", ls="--", lw=0.8)
    ax_step.text(right, HAPTIC_MS * 1.1, "haptic 1 kHz", color="grey", fontsize=8, ha="right")
    ax_step.axhline(VISUAL_MS, color="grey", ls=":", lw=0.8)
    ax_step.text(right, VISUAL_MS * 1.1, "visual 30 Hz", color="grey", fontsize=8, ha="right")
    ax_step.set_title("one explicit step (median; bar: p90)")
    ax_pre.set_title("precompute (build_model)")
    ax_step.legend(fontsize=7, loc="upper left")
    ax_pre.legend(fontsize=7, loc="upper left")
    fig.suptitle(args.title)
    fig.tight_layout()
    out = args.out or args.csv[0].rsplit(".", 1)[0] + ".png"
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
