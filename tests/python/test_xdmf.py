"""The XDMF + HDF5 frame series (output.format "xdmf", docs/outputs.md): one CLI run writing both
series, read back by zona.read_xdmf and compared with its VTU frames; the .h5's layout as h5py
sees it; meshio reading the VTU and the XDMF; zona.run writing the series; bad files."""

import shutil

import numpy as np
import pytest

import zona
from conftest import SMALL, run_cli

pytestmark = pytest.mark.skipif(not zona.XDMF_SUPPORTED, reason="zona built without HDF5")


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """The small scene, 4 frames, written as VTU and as XDMF by the same run."""
    out = tmp_path_factory.mktemp("xdmf") / "run"
    sets = [a for s in SMALL for a in ("--set", s)]
    cli = run_cli("run", "mouse_oocyte", "--quiet", "--frame-count", "4", "--output-format",
                  "vtu+xdmf", *sets, "--out", str(out))
    assert cli.returncode == 0, cli.stderr
    return out


def test_xdmf_frames_equal_the_vtu_frames_of_the_same_run(both):
    series = zona.read_xdmf(both / "frames.xdmf")
    frames = zona.read_pvd(both / "frames.pvd")
    assert len(series) == len(frames) == 4
    # The same times, to the bit (both written as the shortest text of the double).
    np.testing.assert_array_equal(series.times, [f.time for f in frames])
    assert series.times[0] == 0 and np.all(np.diff(series.times) > 0)
    for k, frame in enumerate(frames):
        vtu, xdmf = frame.read(), series[k]
        assert xdmf.time == vtu.time == series.times[k]
        # Geometry: the rest positions in both, and the same tetrahedra and regions.
        np.testing.assert_array_equal(xdmf.points, vtu.points)
        np.testing.assert_array_equal(xdmf.tets, vtu.tets)
        assert xdmf.points_at_rest and vtu.points_at_rest
        assert xdmf.regions == vtu.regions
        np.testing.assert_array_equal(xdmf.deformed_points, vtu.deformed_points)
        # Every point and cell array of the VTU, same shape, same values.
        assert set(xdmf.point_data) == set(vtu.point_data)
        assert set(xdmf.cell_data) == set(vtu.cell_data)
        for name in vtu.point_data:
            np.testing.assert_array_equal(xdmf.point_data[name], vtu.point_data[name], err_msg=name)
        for name in vtu.cell_data:
            np.testing.assert_array_equal(xdmf.cell_data[name], vtu.cell_data[name], err_msg=name)
        assert set(xdmf.field_data) == set(vtu.field_data)
        for name in vtu.field_data:
            np.testing.assert_array_equal(xdmf.field_data[name], vtu.field_data[name], err_msg=name)
    last = series[-1]
    assert {"displacement", "contact", "stress", "strain", "von_mises"} <= set(last.point_data)
    assert last.point_data["stress"].shape == (len(series.points), 3, 3)
    assert np.abs(last.point_data["displacement"]).max() > 1e-7  # the needle moved the cell
    assert "REST positions" in series.note


def test_the_h5_holds_the_mesh_once_and_each_frame(both):
    h5py = pytest.importorskip("h5py")
    vtu = zona.read_pvd(both / "frames.pvd")[-1].read()
    with h5py.File(both / "frames.h5", "r") as h5:
        assert h5["mesh/points"].shape == (len(vtu.points), 3)
        assert h5["mesh/points"].dtype == np.float64
        assert h5["mesh/tets"].dtype == np.int64
        assert h5["mesh/region"].shape == (len(vtu.tets),)
        assert h5.attrs["points_at_rest"] == 1
        assert sorted(h5["frames"]) == ["000000", "000001", "000002", "000003"]
        group = h5["frames/000003"]
        assert group.attrs["time_s"] == vtu.time
        assert group["stress"].shape == (len(vtu.points), 9)
        assert group["green_strain"].shape == (len(vtu.tets), 6)
        np.testing.assert_array_equal(group["displacement"][()], vtu.point_data["displacement"])
        for name, tag in vtu.regions.items():
            assert h5["mesh"].attrs[f"region:{name}"] == tag
    # The mesh is not repeated per frame: the .h5 is smaller than the four .vtu files.
    vtus = sum(p.stat().st_size for p in both.glob("frames_*.vtu"))
    assert (both / "frames.h5").stat().st_size < vtus


def test_meshio_reads_the_vtu_and_the_xdmf(both):
    """meshio 5.3's XDMF support: meshio.read() takes a file of one grid only and refuses a
    Temporal collection (it exits), so the series is read with its TimeSeriesReader (points,
    cells, then each frame's time and arrays)."""
    meshio = pytest.importorskip("meshio")
    vtu = zona.read_pvd(both / "frames.pvd")[-1].read()
    n, m = len(vtu.points), len(vtu.tets)

    mesh = meshio.read(both / "frames_000003.vtu")
    assert mesh.points.shape == (n, 3)
    assert mesh.cells_dict["tetra"].shape == (m, 4)
    np.testing.assert_array_equal(mesh.points, vtu.points)
    assert mesh.point_data["stress"].shape == (n, 9)
    np.testing.assert_array_equal(mesh.point_data["von_mises"], vtu.point_data["von_mises"])
    np.testing.assert_array_equal(mesh.cell_data["von_mises_stress"][0],
                                  vtu.cell_data["von_mises_stress"])

    with meshio.xdmf.TimeSeriesReader(both / "frames.xdmf") as reader:
        points, cells = reader.read_points_cells()
        assert points.shape == (n, 3)
        np.testing.assert_array_equal(points, vtu.points)
        assert cells[0].type == "tetra" and cells[0].data.shape == (m, 4)
        assert reader.num_steps == 4
        t, point_data, cell_data = reader.read_data(3)
        assert t == vtu.time
        assert set(point_data) == set(vtu.point_data)
        np.testing.assert_array_equal(point_data["displacement"], vtu.point_data["displacement"])
        np.testing.assert_array_equal(point_data["stress"].reshape(n, 3, 3), vtu.point_data["stress"])
        np.testing.assert_array_equal(cell_data["green_strain"][0], vtu.cell_data["green_strain"])
        np.testing.assert_array_equal(cell_data["region"][0], vtu.cell_data["region"])
    # meshio.read: "Only supports one grid right now"; its read() then exits (SystemExit).
    with pytest.raises((SystemExit, meshio.ReadError)):
        meshio.read(both / "frames.xdmf")


def test_zona_run_writes_the_series(tmp_path):
    out = tmp_path / "py"
    result = zona.run("mouse_oocyte", sets=SMALL + ["output.format=xdmf"], out=out, frames=2)
    assert (out / "frames.xdmf").exists() and (out / "frames.h5").exists()
    assert not (out / "frames.pvd").exists() and not list(out.glob("frames_*.vtu"))
    assert result.scene["output"]["format"] == "xdmf"
    series = zona.read_xdmf(out / "frames.xdmf")
    assert len(series) == 2
    last = series[-1]
    # The frame's time is the state's (a sum of steps), the last row's the step count times dt.
    assert last.time == pytest.approx(result.time_s[-1], rel=1e-9)
    np.testing.assert_array_equal(last.points, result.rest_positions)
    np.testing.assert_array_equal(last.point_data["displacement"], result.displacement)
    np.testing.assert_array_equal(last.point_data["von_mises"], result.von_mises)
    # A rerun with VTU frames removes the series (zona's own files only).
    (out / "mine.h5").write_text("mine\n")
    zona.run("mouse_oocyte", sets=SMALL, out=out, frames=2)
    assert not (out / "frames.xdmf").exists() and not (out / "frames.h5").exists()
    assert (out / "frames.pvd").exists() and (out / "mine.h5").exists()


def test_bad_series_raise_one_line_errors(both, tmp_path):
    not_xdmf = tmp_path / "a.xdmf"
    not_xdmf.write_text("<VTKFile/>")
    with pytest.raises(zona.ZonaError, match=r"a\.xdmf: not an XDMF 3 file"):
        zona.read_xdmf(not_xdmf)
    not_xdmf.write_text("<Xdmf Version=\"3.0\"><Domain><Grid/>")
    with pytest.raises(zona.ZonaError, match=r"a\.xdmf:1: not XML"):
        zona.read_xdmf(not_xdmf)
    with pytest.raises(zona.ZonaError, match="missing.xdmf: cannot open"):
        zona.read_xdmf(tmp_path / "missing.xdmf")
    # The .xdmf without its .h5, then naming a dataset the .h5 lacks.
    shutil.copy(both / "frames.xdmf", tmp_path / "frames.xdmf")
    with pytest.raises(zona.ZonaError, match=r"frames\.h5: cannot read as HDF5"):
        zona.read_xdmf(tmp_path / "frames.xdmf")
    shutil.copy(both / "frames.h5", tmp_path / "frames.h5")
    text = (both / "frames.xdmf").read_text().replace("/frames/000002/stress", "/frames/000002/nope")
    (tmp_path / "frames.xdmf").write_text(text)
    series = zona.read_xdmf(tmp_path / "frames.xdmf")
    series[1]
    with pytest.raises(zona.ZonaError, match=r"frames\.h5: no dataset /frames/000002/nope"):
        series[2]


def test_xdmf_needs_hdf5_or_is_refused_at_load():
    # With HDF5 (this module) the key loads; the build without it refuses it at load
    # (tests/engine/scene/scene_test.cpp, tests/apps/cmd_run_test.cpp).
    scene = zona.load_scene("mouse_oocyte", sets={"output.format": "xdmf"})
    assert scene["output"]["format"] == "xdmf"
    with pytest.raises(zona.ZonaError, match=r"output\.format: \"hdf\" is not one of"):
        zona.load_scene("mouse_oocyte", sets={"output.format": "hdf"})
