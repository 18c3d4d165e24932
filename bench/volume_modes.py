#!/usr/bin/env python3
"""Element volume ratios near the needle in a run's XDMF frames, and how much of their spread is
nodal pressure's alternating mode (docs/physics.md, "Nodal pressure").

For each frame: J = det F of every tetrahedron; the nodal average Jbar_v (volume-weighted over
the tetrahedra at v, as the law averages it); the mode residual r_e = J_e - mean of Jbar over
e's corners (zero where J varies linearly between elements, and what nodal pressure leaves
unresisted); over the tetrahedra whose rest centroid lies within --radius of --at: J's least,
1st percentile and mean, r's RMS and largest magnitude, and (J - 1)'s RMS. A near-incompressible
material keeps J - 1 of order the shear strain over lambda / mu; an r near (J - 1) says the
volume change there is the alternating mode, not the deformation.

  zona run mouse_oocyte --solver static --set output.frames=47 --set output.format=xdmf --out D
  python3 bench/volume_modes.py D/frames.h5 [--at=-28,0,0] [--radius 6] [--csv OUT.csv]

--at and --radius in micrometres (default: the default scene's needle entry, 28 um before the
cell centre along -x, and 6 um). Needs numpy and h5py (the project's .venv).
"""
import argparse
import sys

import numpy as np


def tet_volume_ratios(points, tets, displacement):
    """J = det F per tetrahedron: deformed over rest signed volume."""
    rest = np.stack([points[tets[:, i]] - points[tets[:, 0]] for i in (1, 2, 3)], axis=2)
    x = points + displacement
    now = np.stack([x[tets[:, i]] - x[tets[:, 0]] for i in (1, 2, 3)], axis=2)
    return np.linalg.det(now) / np.linalg.det(rest), np.abs(np.linalg.det(rest)) / 6


def mode_residual(tets, vertex_count, volume, j):
    """r_e = J_e less the mean over its corners of the volume-weighted nodal average Jbar_v."""
    num = np.zeros(vertex_count)
    den = np.zeros(vertex_count)
    for k in range(4):
        np.add.at(num, tets[:, k], volume * j)
        np.add.at(den, tets[:, k], volume)
    jbar = num / np.where(den > 0, den, 1)
    return j - jbar[tets].mean(axis=1)


def frame_rows(path, at, radius):
    import h5py

    with h5py.File(path, "r") as f:
        points = f["/mesh/points"][:]
        tets = f["/mesh/tets"][:].astype(np.int64)
        centroid = points[tets].mean(axis=1)
        near = np.linalg.norm(centroid - at, axis=1) < radius
        if not near.any():
            raise SystemExit(f"{path}: no tetrahedron within {radius * 1e6:g} um of --at")
        for name in sorted(f["/frames"].keys()):
            group = f["/frames/" + name]
            j, volume = tet_volume_ratios(points, tets, group["displacement"][:])
            r = mode_residual(tets, len(points), volume, j)
            jn, rn = j[near], r[near]
            yield {
                "frame": int(name),
                "time_s": float(group.attrs["time_s"]),
                "J_min": float(jn.min()),
                "J_p1": float(np.percentile(jn, 1)),
                "J_mean": float(jn.mean()),
                "mode_rms": float(np.sqrt((rn ** 2).mean())),
                "mode_max": float(np.abs(rn).max()),
                "dJ_rms": float(np.sqrt(((jn - 1) ** 2).mean())),
                "J_min_all": float(j.min()),
                "inverted": int((j <= 0).sum()),
            }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("frames", help="frames.h5 of a run with output.format xdmf")
    ap.add_argument("--at", default="-28,0,0", help="centre of the region [um], x,y,z")
    ap.add_argument("--radius", type=float, default=6.0, help="radius of the region [um]")
    ap.add_argument("--csv", help="write the rows here too")
    a = ap.parse_args(argv)
    try:
        at = np.array([float(v) for v in a.at.split(",")]) * 1e-6
    except ValueError:
        at = np.zeros(0)
    if at.shape != (3,):
        ap.error(f"--at {a.at}: three numbers x,y,z in um")
    rows = list(frame_rows(a.frames, at, a.radius * 1e-6))
    keys = list(rows[0].keys())
    lines = [",".join(keys)]
    for row in rows:
        lines.append(",".join(f"{row[k]:.6g}" if isinstance(row[k], float) else str(row[k]) for k in keys))
    text = "\n".join(lines) + "\n"
    sys.stdout.write(text)
    if a.csv:
        with open(a.csv, "w") as out:
            out.write(text)


if __name__ == "__main__":
    main()
