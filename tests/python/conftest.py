"""Shared fixtures of the Python module's tests: the zona CLI of the same build, and one small
injection run by the CLI and by zona.run on the same scene (module-scoped: several tests read it).
"""

import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(os.environ.get("ZONA_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))

# The mouse cell at 1500 vertices, needle 20 um, puncture at 2 uN: a quasi-static run that
# punctures in a few seconds (tests/apps/cmd_run_test.cpp runs the same scene through the CLI).
SMALL = ["mesh.generate.vertices=1500", "needle.max_travel=20um", "puncture.threshold=2uN"]


def cli_path():
    path = os.environ.get("ZONA_CLI") or str(ROOT / "build" / "apps" / "zona")
    if not os.access(path, os.X_OK):
        pytest.fail(f"no zona CLI at {path} (set ZONA_CLI)")
    return path


def run_cli(*args, cwd=None):
    """Runs the zona CLI; returns the CompletedProcess (text)."""
    return subprocess.run([cli_path(), *args], capture_output=True, text=True, cwd=cwd,
                          stdin=subprocess.DEVNULL, timeout=300)


@pytest.fixture(scope="session")
def small_runs(tmp_path_factory):
    """The small scene through the CLI (out folder) and through zona.run (out folder and Result),
    same scene, same backend, frames on."""
    import zona

    base = tmp_path_factory.mktemp("small")
    cli_out, py_out = base / "cli", base / "py"
    sets = [a for s in SMALL for a in ("--set", s)]
    cli = run_cli("run", "mouse_oocyte", "--quiet", "--frame-count", "3", *sets, "--out",
                  str(cli_out))
    assert cli.returncode == 0, cli.stderr
    result = zona.run("mouse_oocyte", sets=SMALL, out=py_out, frames=3)
    return {"cli_out": cli_out, "py_out": py_out, "result": result, "cli_stdout": cli.stdout}
