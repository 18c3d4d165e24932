"""zona.generate_mesh and zona.forces against `zona mesh generate` and `zona forces`."""

import numpy as np
import pytest

import zona

from conftest import run_cli


def test_generate_mesh_matches_the_cli(tmp_path):
    mesh = zona.generate_mesh(diameter="56 um", vertices=600, out=tmp_path / "py.msh")
    assert 540 <= len(mesh.points) <= 660  # the mesher's +-10 %
    assert mesh.tets.shape[1] == 4 and mesh.tets.dtype == np.int32
    radius = np.linalg.norm(mesh.points, axis=1).max()
    assert radius == pytest.approx(28e-6, rel=0.02)
    cli = run_cli("mesh", "generate", "--diameter", "56um", "--vertices", "600", "--out",
                  str(tmp_path / "cli.msh"))
    assert cli.returncode == 0, cli.stderr
    a, b = zona.read_mesh(tmp_path / "py.msh"), zona.read_mesh(tmp_path / "cli.msh")
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.tets, b.tets)
    # Metres and text with a unit are the same length.
    again = zona.generate_mesh(diameter=56e-6, vertices=600)
    np.testing.assert_array_equal(again.points, mesh.points)


def test_generate_mesh_from_a_scene_and_errors():
    mesh = zona.generate_mesh("mouse_oocyte", vertices=800)
    assert 720 <= len(mesh.points) <= 880
    assert set(mesh.regions) >= {"zona"}
    with pytest.raises(zona.ZonaError, match="diameter"):
        zona.generate_mesh(diameter="56 kPa", vertices=500)
    with pytest.raises(zona.ZonaError, match="vertices or edge_length"):
        zona.generate_mesh(diameter="56 um")


def test_forces_match_the_cli_and_scale_with_e(tmp_path):
    mesh = zona.generate_mesh(diameter="56 um", vertices=300, out=tmp_path / "rest.vtu")
    assert np.abs(zona.forces(mesh, mesh.points)).max() == 0  # at rest: no force
    # Stretch along x by 1 %.
    deformed = mesh.points * np.array([1.01, 1.0, 1.0])
    zona.Mesh(deformed, mesh.tets, mesh.region).write(tmp_path / "deformed.vtu")
    f = zona.forces(tmp_path / "rest.vtu", tmp_path / "deformed.vtu", model="linear",
                    young=10e3, poisson=0.3, out=tmp_path / "py.csv")
    cli = run_cli("forces", str(tmp_path / "rest.vtu"), str(tmp_path / "deformed.vtu"),
                  "--model", "linear", "--young", "10000", "--poisson", "0.3", "--backend", "cpu",
                  "--out", str(tmp_path / "cli.csv"))
    assert cli.returncode == 0, cli.stderr
    table = np.loadtxt(tmp_path / "cli.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(f, table[:, 1:])
    assert (tmp_path / "py.csv").read_text() == (tmp_path / "cli.csv").read_text()
    # The linear law: twice E, twice the force; the net force of internal forces is zero.
    f2 = zona.forces(mesh, deformed, model="linear", young=20e3, poisson=0.3)
    np.testing.assert_allclose(f2, 2 * f, rtol=1e-12, atol=1e-15 * np.abs(f).max())
    np.testing.assert_allclose(f.sum(axis=0), 0, atol=1e-9 * np.abs(f).max())
    with pytest.raises(zona.ZonaError, match="3 vertices, but the rest mesh has"):
        zona.forces(mesh, deformed[:3])
    with pytest.raises(zona.ZonaError, match="model"):
        zona.forces(mesh, deformed, model="rubber")
