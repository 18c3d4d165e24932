"""The readers against zona's own outputs (the CLI's), and against bad files."""

import json

import numpy as np
import pytest

import zona


def test_force_csv_round_trips(small_runs, tmp_path):
    path = small_runs["cli_out"] / "force.csv"
    table = zona.read_force_csv(path)
    assert table.schema_version == zona.SCHEMA_VERSION
    assert list(table) == list(zona.FORCE_CSV_COLUMNS)
    # The same numbers as numpy's own reading of the file.
    raw = np.loadtxt(path, delimiter=",", skiprows=2)
    for i, name in enumerate(table):
        np.testing.assert_array_equal(table[name], raw[:, i].astype(table[name].dtype), err_msg=name)
    assert table.punctured.any() and not table.punctured[0]


def test_summary_is_the_dict_of_the_file(small_runs):
    path = small_runs["cli_out"] / "summary.json"
    summary = zona.read_summary(path)
    assert summary == json.loads(path.read_text())
    assert summary["schema_version"] == zona.SCHEMA_VERSION
    assert summary["provenance"]["command"].split()[1] == "run"


def test_pvd_and_vtu_read_the_cli_frames(small_runs):
    frames = zona.read_pvd(small_runs["cli_out"] / "frames.pvd")
    assert len(frames) == 3
    times = [f.time for f in frames]
    assert times[0] == 0 and times == sorted(times)
    first, last = frames[0].read(), frames[-1].read()
    assert first.points_at_rest and first.time == 0
    np.testing.assert_array_equal(first.points, last.points)  # rest positions in every frame
    assert np.abs(first.point_data["displacement"]).max() == 0
    assert last.point_data["stress"].shape == (len(last.points), 3, 3)
    assert {"region", "green_strain", "von_mises_stress"} <= set(last.cell_data)
    np.testing.assert_array_equal(last.deformed_points, last.points + last.point_data["displacement"])
    # read_mesh reads the same file as a mesh, the same points.
    mesh = zona.read_mesh(frames[-1].path)
    np.testing.assert_array_equal(mesh.points, last.points)
    # The Python run's last frame is the CLI's: the same state.
    py_last = zona.read_pvd(small_runs["py_out"] / "frames.pvd")[-1].read()
    np.testing.assert_array_equal(py_last.point_data["displacement"], last.point_data["displacement"])


def test_bad_files_raise_one_line_errors(tmp_path):
    csv = tmp_path / "force.csv"
    csv.write_text("# zona force.csv schema 3 (docs/outputs.md)\ntime_s,force_N\n0,1\n1,2,3\n")
    with pytest.raises(zona.ZonaError, match=r"force\.csv:4: 3 values for 2 columns"):
        zona.read_force_csv(csv)
    csv.write_text("time_s,force_N\n0,abc\n")
    with pytest.raises(zona.ZonaError, match=r"force\.csv:2: a value is not a number"):
        zona.read_force_csv(csv)
    with pytest.raises(zona.ZonaError, match="missing.csv: cannot open"):
        zona.read_force_csv(tmp_path / "missing.csv")
    summary = tmp_path / "summary.json"
    summary.write_text("{\"a\": 1,\n")
    with pytest.raises(zona.ZonaError, match=r"summary\.json:2: not JSON"):
        zona.read_summary(summary)
    summary.write_text("{\"a\": 1}")
    with pytest.raises(zona.ZonaError, match="not a zona summary"):
        zona.read_summary(summary)
    vtu = tmp_path / "frame.vtu"
    vtu.write_text("<VTKFile type=\"PolyData\"></VTKFile>")
    with pytest.raises(zona.ZonaError, match=r"frame\.vtu:1: VTK file type 'PolyData'") as caught:
        zona.read_vtu(vtu)
    assert "\n" not in str(caught.value)
    pvd = tmp_path / "frames.pvd"
    pvd.write_text("<VTKFile type=\"Collection\"><Collection><DataSet file=\"a.vtu\"/></Collection></VTKFile>")
    with pytest.raises(zona.ZonaError, match="DataSet 0 needs file and timestep"):
        zona.read_pvd(pvd)
    pvd.write_text("<VTKFile")
    with pytest.raises(zona.ZonaError, match=r"frames\.pvd:1: not XML"):
        zona.read_pvd(pvd)
