#!/usr/bin/env python3
"""Force-deformation plots of zona's outputs, as PNG and SVG (matplotlib).

`zona run`, `zona study convergence` and `zona plot` call this script (docs/plots.md); it also
runs on its own:

    python3 python/zona_plot.py force --run out/a --run out/b:stiffer --data measured.csv \
        --out overlay
    python3 python/zona_plot.py convergence --study out/study --out out/study/convergence

Every figure has the same two panels: the loading branch (deformation [um] against needle
force [uN]) ending at the puncture, which is marked, and, beside it on the same force axis, the
branch after puncture against the needle's travel past the puncture point. After puncture the
deformation at the entry point falls back while the needle goes on, so drawn against deformation
that branch would run back over the loading curve. Each figure is written as STEM.png and
STEM.svg. Errors are one line on stderr ("zona plot: FILE: ...") and exit status 1; a missing
matplotlib is exit status 3.
"""

import argparse
import csv
import json
import math
import os
import sys

# One axis label per quantity, in every figure.
DEFORMATION_LABEL = "deformation [um]"
FORCE_LABEL = "needle force [uN]"
TRAVEL_LABEL = "needle travel past puncture [um]"

EXIT_ERROR = 1
EXIT_NO_MATPLOTLIB = 3


class PlotError(Exception):
    """Bad input: the message names the file or the argument."""


class Curve:
    """One simulated curve: the loading branch [um, uN] up to and including the puncture point,
    the branch after it (needle travel past puncture [um], force [uN]), the puncture or None."""

    def __init__(self, label):
        self.label = label
        self.load_d, self.load_f = [], []
        self.post_travel, self.post_f = [], []
        self.puncture = None  # (deformation [um], force [uN])


class Measured:
    """Measured points [um, uN] with an optional error per point [uN] (std or sem)."""

    def __init__(self, label, d, f, err, err_kind):
        self.label, self.d, self.f, self.err, self.err_kind = label, d, f, err, err_kind


def split_label(spec):
    """'PATH[:label]' -> (PATH, label or None). A ':' inside the path is kept when the part after
    the last ':' names an existing file (so 'a:b.csv' as a file name still works)."""
    colon = spec.rfind(":")
    if colon <= 0 or os.path.exists(spec):
        return spec, None
    return spec[:colon], spec[colon + 1 :] or None


def read_table(path):
    """Header and rows of a CSV whose '#' lines are comments; cells stay strings."""
    if not os.path.exists(path):
        raise PlotError(f"{path}: not found")
    if not os.path.isfile(path):
        raise PlotError(f"{path}: is not a regular file")
    try:
        with open(path, newline="", encoding="utf-8") as f:
            lines = [line for line in f if line.strip() and not line.lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as e:
        raise PlotError(f"{path}: cannot read ({e})") from None
    if not lines:
        raise PlotError(f"{path}: empty (no header)")
    rows = list(csv.reader(lines))
    header = [h.strip() for h in rows[0]]
    return header, rows[1:]


def column(path, header, names):
    """Index of the first of `names` in the header, else None."""
    for name in names:
        if name in header:
            return header.index(name)
    return None


def number(path, row_number, cells, index, name):
    try:
        value = float(cells[index])
    except (IndexError, ValueError):
        raise PlotError(f"{path}: data row {row_number}: {name} is not a number") from None
    if not math.isfinite(value):
        raise PlotError(f"{path}: data row {row_number}: {name} is not finite")
    return value


def close_branch(curve):
    """The puncture point closes the loading branch (the force the criterion fired at) and
    opens the branch after it (at zero travel past puncture)."""
    if curve.puncture is not None:
        curve.load_d.append(curve.puncture[0])
        curve.load_f.append(curve.puncture[1])
        if curve.post_f:
            curve.post_travel.insert(0, 0.0)
            curve.post_f.insert(0, curve.puncture[1])


def read_run(spec):
    """A run of `zona run`: its folder or its force.csv (docs/outputs.md), with summary.json's
    puncture point when the folder has one."""
    path, label = split_label(spec)
    csv_path = os.path.join(path, "force.csv") if os.path.isdir(path) else path
    header, rows = read_table(csv_path)
    need = ["deformation_m", "force_N", "punctured"]
    missing = [name for name in need if name not in header]
    if missing:
        raise PlotError(f"{csv_path}: not a zona force.csv (no column {', '.join(missing)})")
    i_d, i_f, i_p = (header.index(n) for n in need)
    i_t = column(csv_path, header, ["needle_travel_m"])
    folder = os.path.dirname(os.path.abspath(csv_path))
    curve = Curve(label or os.path.basename(folder))
    # The puncture as the run recorded it (summary.json); else the last row before the flag.
    summary = os.path.join(folder, "summary.json")
    puncture_travel = None
    if os.path.isfile(summary):
        try:
            with open(summary, encoding="utf-8") as f:
                p = json.load(f).get("puncture", {})
        except (OSError, ValueError) as e:
            raise PlotError(f"{summary}: cannot read ({e})") from None
        if p.get("punctured") and "deformation_m" in p and "force_N" in p:
            curve.puncture = (p["deformation_m"] * 1e6, p["force_N"] * 1e6)
            if "needle_travel_m" in p:
                puncture_travel = p["needle_travel_m"] * 1e6
    last_before = None
    for n, cells in enumerate(rows, 1):
        d = number(csv_path, n, cells, i_d, "deformation_m") * 1e6
        f = number(csv_path, n, cells, i_f, "force_N") * 1e6
        t = number(csv_path, n, cells, i_t, "needle_travel_m") * 1e6 if i_t is not None else None
        if number(csv_path, n, cells, i_p, "punctured") == 0:
            curve.load_d.append(d)
            curve.load_f.append(f)
            last_before = (d, f, t)
        else:
            if curve.puncture is None and last_before is not None:
                curve.puncture = last_before[:2]
            if puncture_travel is None:
                puncture_travel = last_before[2] if last_before and last_before[2] is not None else t
            if t is not None:
                curve.post_travel.append(t - puncture_travel)
                curve.post_f.append(f)
    if not curve.load_d and not curve.post_f:
        raise PlotError(f"{csv_path}: no data rows")
    close_branch(curve)
    return curve


def read_measured(spec):
    """Measured points: columns deformation_m or deformation_um, force_N or force_uN, and
    optionally an error column (force_std_*, force_sem_*, or std / sem in the force's unit)."""
    path, label = split_label(spec)
    header, rows = read_table(path)
    i_d = column(path, header, ["deformation_m", "deformation_um"])
    i_f = column(path, header, ["force_N", "force_uN"])
    if i_d is None or i_f is None:
        raise PlotError(f"{path}: the header needs deformation_m (or deformation_um) and force_N "
                        f"(or force_uN)")
    d_scale = 1e6 if header[i_d] == "deformation_m" else 1.0
    f_scale = 1e6 if header[i_f] == "force_N" else 1.0
    err_names = {"force_std_N": 1e6, "force_sem_N": 1e6, "force_std_uN": 1.0,
                 "force_sem_uN": 1.0, "std": f_scale, "sem": f_scale}
    i_e = column(path, header, list(err_names))
    d, f, err = [], [], []
    for n, cells in enumerate(rows, 1):
        d.append(number(path, n, cells, i_d, header[i_d]) * d_scale)
        f.append(number(path, n, cells, i_f, header[i_f]) * f_scale)
        if i_e is not None:
            err.append(abs(number(path, n, cells, i_e, header[i_e])) * err_names[header[i_e]])
    if not d:
        raise PlotError(f"{path}: no data rows")
    kind = None
    if i_e is not None:
        kind = "sem" if "sem" in header[i_e] else "std"
    name = label or os.path.splitext(os.path.basename(path))[0]
    return Measured(name, d, f, err if i_e is not None else None, kind)


def read_study(folder):
    """The curves of `zona study convergence`: convergence.csv (one row per size and sample)
    and convergence_summary.csv (the puncture per size)."""
    samples = os.path.join(folder, "convergence.csv")
    header, rows = read_table(samples)
    need = ["vertices", "travel_um", "deformation_um", "force_un", "punctured"]
    missing = [name for name in need if name not in header]
    if missing:
        raise PlotError(f"{samples}: not a zona convergence.csv (no column {', '.join(missing)})")
    i_v, i_t, i_d, i_f, i_p = (header.index(n) for n in need)
    punctures = {}
    summary = os.path.join(folder, "convergence_summary.csv")
    if os.path.isfile(summary):
        s_header, s_rows = read_table(summary)
        keys = ["vertices", "punctured", "puncture_deformation_um", "puncture_force_un"]
        if all(k in s_header for k in keys):
            j_v, j_p, j_d, j_f = (s_header.index(k) for k in keys)
            for n, cells in enumerate(s_rows, 1):
                if len(cells) > j_f and cells[j_p].strip() == "1":
                    punctures[cells[j_v]] = (number(summary, n, cells, j_d, keys[2]),
                                             number(summary, n, cells, j_f, keys[3]))
    curves, by_size, travel_at = [], {}, {}
    for n, cells in enumerate(rows, 1):
        if len(cells) <= max(i_v, i_t, i_d, i_f, i_p):
            raise PlotError(f"{samples}: data row {n}: too few columns")
        size = cells[i_v]
        if size not in by_size:
            by_size[size] = Curve(f"{size} vertices")
            by_size[size].puncture = punctures.get(size)
            curves.append(by_size[size])
        c = by_size[size]
        t = number(samples, n, cells, i_t, "travel_um")
        f = number(samples, n, cells, i_f, "force_un")
        if number(samples, n, cells, i_p, "punctured") == 0:
            if c.post_f:
                continue  # a loading row after puncture rows: not expected, not drawn
            c.load_d.append(number(samples, n, cells, i_d, "deformation_um"))
            c.load_f.append(f)
            travel_at[size] = t
        else:
            c.post_travel.append(t - travel_at.get(size, t))
            c.post_f.append(f)
    if not curves:
        raise PlotError(f"{samples}: no data rows")
    for c in curves:
        close_branch(c)
    return curves


def parse_reference(spec):
    """'DEFORMATION_UM,FORCE_UN[:label]' -> (d, f, label)."""
    values, _, label = spec.partition(":")
    try:
        d, f = (float(x) for x in values.split(","))
    except ValueError:
        raise PlotError(f"--reference: expected DEFORMATION_UM,FORCE_UN[:label], got '{spec}'") from None
    return d, f, label or values


def figure(title, curves, measured, references, stem):
    """Draws the two panels and writes STEM.png and STEM.svg; returns the two paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # SVG text as text (searchable, editable) and the same bytes for the same data.
    plt.rcParams.update({"svg.fonttype": "none", "svg.hashsalt": "zona", "font.size": 10})
    after = any(c.post_f for c in curves)
    if after:
        fig, (ax, ax_after) = plt.subplots(1, 2, figsize=(10.0, 5.0), sharey=True,
                                           layout="constrained",
                                           gridspec_kw={"width_ratios": [2.6, 1.4]})
    else:
        fig, ax = plt.subplots(figsize=(7.5, 5.0), layout="constrained")
        ax_after = None
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    xs, ys = [], []
    for k, c in enumerate(curves):
        colour = colours[k % len(colours)]
        ax.plot(c.load_d, c.load_f, "-", color=colour, lw=1.8, label=c.label)
        xs += c.load_d
        ys += c.load_f
        if c.puncture is not None:
            ax.plot([c.puncture[0]], [c.puncture[1]], "X", color=colour, ms=9, mec="black",
                    mew=0.8, label=f"puncture {c.puncture[0]:.1f} um, {c.puncture[1]:.2f} uN")
        if ax_after is not None and c.post_f:
            ax_after.plot(c.post_travel, c.post_f, "--", color=colour, lw=1.5)
            ys += c.post_f
    for m in measured:
        if m.err is not None:
            ax.errorbar(m.d, m.f, yerr=m.err, fmt="o", color="black", ms=5, capsize=3, lw=1,
                        label=f"{m.label} (mean +/- {m.err_kind})")
        else:
            ax.plot(m.d, m.f, "o", color="black", ms=5, mfc="white", label=m.label)
        xs += m.d
        ys += [f + (m.err[i] if m.err else 0) for i, f in enumerate(m.f)]
    for d, f, label in references:
        ax.plot([d], [f], "D", color="black", ms=7, label=label)
        xs.append(d)
        ys.append(f)
    # Axes start at the data: the deformation axis at the smallest deformation drawn, the
    # force axis at zero or the smallest force.
    if xs:
        lo, hi = min(xs), max(xs)
        ax.set_xlim(lo, hi + 0.03 * (hi - lo if hi > lo else 1.0))
    if ys:
        lo, hi = min(0.0, min(ys)), max(ys)
        ax.set_ylim(lo, hi + 0.05 * (hi - lo if hi > lo else 1.0))
    ax.set_xlabel(DEFORMATION_LABEL)
    ax.set_ylabel(FORCE_LABEL)
    ax.grid(True, color="0.9")
    ax.legend(loc="upper left", fontsize=8, frameon=False)
    if ax_after is not None:
        ax_after.set_xlabel(TRAVEL_LABEL)
        ax_after.set_title("after puncture", fontsize=9)
        ax_after.grid(True, color="0.9")
        ax_after.tick_params(labelleft=False)
    if title:
        fig.suptitle(title)
    paths = [stem + ".png", stem + ".svg"]
    try:
        fig.savefig(paths[0], dpi=150)
        fig.savefig(paths[1], metadata={"Date": None})
    except OSError as e:
        raise PlotError(f"{e.filename or stem}: cannot write ({e.strerror})") from None
    finally:
        plt.close(fig)
    return paths


def output_stem(out):
    """--out as STEM, STEM.png or STEM.svg."""
    stem, ext = os.path.splitext(out)
    return stem if ext.lower() in (".png", ".svg") else out


def main(argv):
    parser = argparse.ArgumentParser(prog="zona_plot.py", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="kind", required=True)
    force = sub.add_parser("force", help="runs' force.csv and measured data, overlaid")
    force.add_argument("--run", action="append", default=[], help="run folder or force.csv[:label]")
    force.add_argument("--data", action="append", default=[], help="measured CSV[:label]")
    force.add_argument("--reference", action="append", default=[],
                       help="DEFORMATION_UM,FORCE_UN[:label]")
    force.add_argument("--title", default="")
    force.add_argument("--out", required=True, help="STEM: writes STEM.png and STEM.svg")
    study = sub.add_parser("convergence", help="the curves of zona study convergence")
    study.add_argument("--study", required=True, help="the study's output folder")
    study.add_argument("--title", default="")
    study.add_argument("--out", required=True, help="STEM: writes STEM.png and STEM.svg")
    args = parser.parse_args(argv)
    try:
        # The inputs first: a bad file is reported before matplotlib loads.
        if args.kind == "force":
            if not args.run and not args.data:
                raise PlotError("nothing to plot: give a run (force.csv or its folder) or --data")
            curves = [read_run(r) for r in args.run]
            measured = [read_measured(m) for m in args.data]
            references = [parse_reference(r) for r in args.reference]
        else:
            curves, measured, references = read_study(args.study), [], []
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            print(f"zona plot: matplotlib is not installed for {sys.executable} "
                  "(bash scripts/setup.sh installs it into .venv)", file=sys.stderr)
            return EXIT_NO_MATPLOTLIB
        stem = output_stem(args.out)
        if os.path.dirname(stem) and not os.path.isdir(os.path.dirname(stem)):
            raise PlotError(f"{os.path.dirname(stem)}: no such folder")
        paths = figure(args.title, curves, measured, references, stem)
    except PlotError as e:
        print(f"zona plot: {e}", file=sys.stderr)
        return EXIT_ERROR
    print(" ".join(paths))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
