"""bench/volume_modes.py: element volume ratios and nodal pressure's alternating mode, on a
frames.h5 written here (docs/physics.md, "Nodal pressure")."""

import importlib.util

import numpy as np
import pytest

from conftest import ROOT

h5py = pytest.importorskip("h5py")


def load_tool():
    spec = importlib.util.spec_from_file_location("volume_modes", ROOT / "bench" / "volume_modes.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def cube_mesh(n, size):
    """An n x n x n grid of cubes of edge size/n centred on the origin, six tetrahedra each."""
    g = np.linspace(-size / 2, size / 2, n + 1)
    points = np.array([[x, y, z] for x in g for y in g for z in g])
    index = lambda i, j, k: (i * (n + 1) + j) * (n + 1) + k
    tets = []
    for i in range(n):
        for j in range(n):
            for k in range(n):
                c = [index(i + a, j + b, k + d) for a in (0, 1) for b in (0, 1) for d in (0, 1)]
                # The cube's six tetrahedra around its 0-7 diagonal (positive orientation).
                for a, b in ((1, 3), (3, 2), (2, 6), (6, 4), (4, 5), (5, 1)):
                    t = [c[0], c[a], c[b], c[7]]
                    p = points[t]
                    if np.linalg.det(np.stack([p[1] - p[0], p[2] - p[0], p[3] - p[0]], axis=1)) < 0:
                        t[1], t[2] = t[2], t[1]
                    tets.append(t)
    return points, np.array(tets, dtype=np.int64)


def write_frames(path, points, tets, displacements):
    with h5py.File(path, "w") as f:
        f["/mesh/points"] = points
        f["/mesh/tets"] = tets
        for i, u in enumerate(displacements):
            f[f"/frames/{i:06d}/displacement"] = u
            f[f"/frames/{i:06d}"].attrs["time_s"] = 0.1 * i


def test_an_affine_compression_has_no_mode_and_a_moved_vertex_has_one(tmp_path):
    tool = load_tool()
    points, tets = cube_mesh(2, 4e-6)
    affine = points @ np.diag([-0.2, 0.0, 0.0])  # J = 0.8 everywhere
    moved = np.zeros_like(points)
    centre = int(np.argmin(np.linalg.norm(points, axis=1)))
    moved[centre] = [0.5e-6, 0.2e-6, 0.0]  # the elements around it change volume unevenly
    write_frames(tmp_path / "frames.h5", points, tets, [np.zeros_like(points), affine, moved])
    rows = list(tool.frame_rows(str(tmp_path / "frames.h5"), np.zeros(3), 10e-6))
    assert [r["frame"] for r in rows] == [0, 1, 2]
    assert rows[0]["J_min"] == pytest.approx(1.0) and rows[0]["mode_rms"] == pytest.approx(0.0, abs=1e-12)
    assert rows[1]["J_mean"] == pytest.approx(0.8) and rows[1]["dJ_rms"] == pytest.approx(0.2)
    assert rows[1]["mode_rms"] == pytest.approx(0.0, abs=1e-12)
    # Moving one vertex: the volume change alternates between its elements.
    assert rows[2]["mode_rms"] > 0.3 * rows[2]["dJ_rms"] > 0
    assert rows[2]["J_min"] < 1 < rows[2]["J_min"] + 2 * rows[2]["mode_max"]
    assert rows[2]["inverted"] == 0


def test_a_region_with_no_element_is_a_one_line_error(tmp_path, capsys):
    tool = load_tool()
    points, tets = cube_mesh(1, 1e-6)
    write_frames(tmp_path / "frames.h5", points, tets, [np.zeros_like(points)])
    with pytest.raises(SystemExit, match="no tetrahedron within"):
        tool.main([str(tmp_path / "frames.h5"), "--at=100,0,0", "--radius", "1"])
    with pytest.raises(SystemExit):
        tool.main([str(tmp_path / "frames.h5"), "--at", "1,2"])
    assert "three numbers" in capsys.readouterr().err
