"""zona.run against `zona run`: the same scene gives the same curve, puncture and summary; the
final fields are the last frame's; E moves the force the right way; progress, stop and Ctrl-C."""

import json
import os
import signal
import threading

import numpy as np
import pytest

import zona

from conftest import SMALL


def test_small_scene_punctures_as_the_cli_does(small_runs):
    r = small_runs["result"]
    cli = zona.read_summary(small_runs["cli_out"] / "summary.json")
    assert r.puncture["punctured"] and cli["puncture"]["punctured"]
    assert "puncture: t " in small_runs["cli_stdout"]
    for key in ("time_s", "needle_travel_m", "deformation_m", "force_N"):
        assert r.puncture[key] == pytest.approx(cli["puncture"][key], rel=1e-12, abs=0), key
    assert r.quasi_static is True and cli["quasi_static"] is True
    assert not r.interrupted
    assert r.summary["schema_version"] == zona.SCHEMA_VERSION
    assert r.summary["backend_kind"] == "cpu"
    assert r.summary["provenance"]["command"].startswith("python")
    assert r.summary["mesh"] == cli["mesh"]
    assert r.summary["peak_force_N"] == pytest.approx(cli["peak_force_N"], rel=1e-12)


def test_arrays_match_the_cli_force_csv(small_runs):
    r = small_runs["result"]
    csv = zona.read_force_csv(small_runs["cli_out"] / "force.csv")
    assert list(r.columns) == list(zona.FORCE_CSV_COLUMNS) == list(csv)
    n = len(csv["time_s"])
    assert n > 100 and len(r.time_s) == n
    for name in zona.FORCE_CSV_COLUMNS:
        # Written with 17 significant digits but imbalance and kinetic_share with 9.
        np.testing.assert_allclose(r.columns[name], csv[name], rtol=1e-8, atol=0, err_msg=name)
    assert r.columns["punctured"].dtype == bool and r.columns["contacts"].dtype == np.int32
    # The rows up to the puncture reach its force (threshold 2 uN), the rows after it say so.
    before = ~r.punctured
    assert before[0] and not before[-1]
    assert r.force_N[before][-1] == pytest.approx(r.puncture["force_N"], rel=0.01)
    assert r.force_N[before].max() <= r.summary["peak_force_N"]


def test_module_outputs_match_the_cli_outputs(small_runs):
    py, cli = small_runs["py_out"], small_runs["cli_out"]
    assert sorted(p.name for p in py.iterdir()) == sorted(
        p.name for p in cli.iterdir() if p.suffix not in (".png", ".svg"))  # the plots: zona plot
    a, b = zona.read_force_csv(py / "force.csv"), zona.read_force_csv(cli / "force.csv")
    assert a.schema_version == b.schema_version == zona.SCHEMA_VERSION
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert json.loads((py / "scene.json").read_text()) == json.loads((cli / "scene.json").read_text())


def test_final_fields_are_the_last_frame(small_runs):
    r = small_runs["result"]
    frames = zona.read_pvd(small_runs["py_out"] / "frames.pvd")
    assert len(frames) == 3
    last = frames[-1].read()
    assert last.time == pytest.approx(r.time_s[-1], rel=1e-12)
    np.testing.assert_array_equal(last.points, r.rest_positions)
    np.testing.assert_array_equal(last.tets, r.tets)
    np.testing.assert_array_equal(last.point_data["displacement"], r.displacement)
    np.testing.assert_array_equal(last.point_data["stress"], r.stress)
    np.testing.assert_array_equal(last.point_data["strain"], r.strain)
    np.testing.assert_array_equal(last.point_data["von_mises"], r.von_mises)
    n = len(r.rest_positions)
    assert r.stress.shape == (n, 3, 3) and r.von_mises.shape == (n,)
    # Cauchy stress is symmetric; the vertices the needle pushed moved (16 um at the puncture;
    # the cell springs back as the tip's load is released, to about 3 um at the end).
    np.testing.assert_allclose(r.stress, np.transpose(r.stress, (0, 2, 1)), atol=1e-9 * np.abs(r.stress).max())
    assert np.abs(r.displacement).max() > 1e-6
    np.testing.assert_allclose(r.deformed_positions, r.rest_positions + r.displacement)
    assert r.regions and set(np.unique(r.tet_region)) <= set(r.regions.values())


def test_arrays_are_views_kept_alive_by_the_result(small_runs):
    r = small_runs["result"]
    # Views into engine memory: no numpy copy owns the data.
    assert not r.displacement.flags.owndata and not r.rest_positions.flags.owndata
    view = r.point_fields["stress"]
    del r
    assert np.isfinite(view).all()


def stiffer_force(young):
    scene = zona.load_scene("mouse_oocyte", sets=["mesh.generate.vertices=1000",
                                                  "needle.max_travel=8um",
                                                  "puncture.criterion=none"])
    scene["materials"]["default"]["young"] = young
    r = zona.run(scene)
    return r.deformation_m[-1], r.force_N[-1]


def test_a_stiffer_cell_takes_more_force():
    d_soft, f_soft = stiffer_force("16.5 kPa")
    d_stiff, f_stiff = stiffer_force("33 kPa")
    assert f_soft > 0
    # The needle's travel is prescribed; the stiffer cell dents less and pushes back harder.
    assert f_stiff > 1.3 * f_soft
    assert d_stiff <= d_soft * 1.05


def long_scene():
    return zona.load_scene("mouse_oocyte", sets=["mesh.generate.vertices=1000",
                                                 "puncture.criterion=none"])


def test_progress_is_called_and_returning_false_stops_the_run(tmp_path):
    calls = []

    def progress(p):
        calls.append(p)
        return len(calls) < 2  # False at the second call: stop

    r = zona.run(long_scene(), progress=progress, progress_interval=0.0, out=tmp_path)
    assert len(calls) == 2
    assert calls[0]["time_s"] > 0 and calls[0]["end_time_s"] > calls[0]["time_s"]
    assert r.interrupted and r.summary["interrupted"] is True
    assert r.time_s[-1] < 0.5 * calls[0]["end_time_s"]
    # What was written says so, up to where it stopped.
    assert zona.read_summary(tmp_path / "summary.json")["interrupted"] is True
    csv = zona.read_force_csv(tmp_path / "force.csv")
    np.testing.assert_allclose(csv["time_s"], r.time_s, rtol=1e-15)


def test_ctrl_c_stops_the_run_and_raises_keyboard_interrupt(tmp_path):
    # SIGINT from another thread once the run is under way (its first progress call): Python's
    # handler sets the flag, the run's signal check sees it between batches of steps.
    started = threading.Event()
    main = threading.get_ident()

    def interrupt():
        started.wait(60)
        signal.pthread_kill(main, signal.SIGINT)

    killer = threading.Thread(target=interrupt)
    killer.start()
    seen = []

    def progress(p):
        seen.append(p["time_s"])
        started.set()

    with pytest.raises(KeyboardInterrupt) as caught:
        zona.run(long_scene(), progress=progress, progress_interval=0.0, out=tmp_path)
    killer.join()
    r = caught.value.result
    assert r.interrupted and r.summary["interrupted"] is True
    assert r.time_s[-1] < r.summary["numerics"]["simulated_time_s"] + 1e-12
    assert r.time_s[-1] < 0.5 * 0.46  # far from the scene's end (46 um at 0.1 mm/s)
    assert zona.read_summary(tmp_path / "summary.json")["interrupted"] is True


def test_an_exception_in_progress_stops_the_run_and_is_raised():
    def progress(p):
        raise RuntimeError("stop here")

    with pytest.raises(RuntimeError, match="stop here") as caught:
        zona.run(long_scene(), progress=progress, progress_interval=0.0)
    assert caught.value.result.interrupted


def test_bad_input_raises_one_line_errors(tmp_path):
    with pytest.raises(zona.ZonaError, match="no_such_scene"):
        zona.run("no_such_scene")
    scene = zona.load_scene("mouse_oocyte")
    scene["materials"]["default"]["young"] = "17 kg"
    with pytest.raises(zona.ZonaError, match=r"materials\.default\.young") as caught:
        zona.run(scene)
    assert "\n" not in str(caught.value)
    with pytest.raises(zona.ZonaError, match="needle.speed"):
        zona.run("mouse_oocyte", sets=["needle.speed=fast"])
    with pytest.raises(zona.ZonaError, match="backend"):
        zona.run("mouse_oocyte", backend="abacus")
    with pytest.raises(TypeError):
        zona.run("mouse_oocyte", no_such_option=1)


def test_static_solver_through_the_module():
    """solver.method "static" from Python: converged rows with their Newton columns, a puncture
    at its threshold, and the summary says which solver ran."""
    r = zona.run("mouse_oocyte", sets=["mesh.generate.vertices=600", "needle.max_travel=12um",
                                       "puncture.threshold=0.8uN", "solver.method=static"])
    assert r.summary["solver"] == "static"
    assert r.summary["static_solver"]["linear"] in ("cg", "direct")
    assert r.puncture["punctured"]
    assert r.puncture["force_N"] == pytest.approx(0.8e-6, rel=0.01)
    rows = r.columns["newton_iterations"] > 0
    assert rows.sum() >= 5
    # Each row converged: the residual below 1e-5 of max(force, E r^2) (E 16.5 kPa, r 4 um).
    scale = np.maximum(np.abs(r.force_N[rows]), 16.5e3 * 4e-6 ** 2)
    assert np.all(r.columns["residual_N"][rows] <= 1e-5 * scale * (1 + 1e-9))
