"""zona from Python: load a scene as a dict, run it, get numpy arrays (docs/python.md).

    import zona
    scene = zona.load_scene("mouse_oocyte", sets=["mesh.generate.vertices=1500"])
    result = zona.run(scene)
    result.deformation_m, result.force_N    # the force-deformation curve [m], [N]
"""

import json
import os
import shlex
import sys
import warnings

import numpy as np

from . import _zona
from ._readers import Columns, Frame, Vtu, read_force_csv, read_pvd, read_summary, read_vtu
from ._result import Result
from ._xdmf import XdmfSeries, read_xdmf
from ._zona import ZonaError

__version__ = _zona.version
#: Version of the output schema (force.csv's and summary.json's; docs/outputs.md).
SCHEMA_VERSION = _zona.schema_version
#: force.csv's column names, in order.
FORCE_CSV_COLUMNS = tuple(_zona.force_csv_columns)
#: Whether this build writes XDMF + HDF5 frames (output.format "xdmf"; a build with libhdf5).
XDMF_SUPPORTED = bool(_zona.xdmf_supported)

__all__ = [
    "Columns", "Frame", "Mesh", "NotQuasiStaticWarning", "Result", "Vtu", "XdmfSeries",
    "ZonaError", "find_scene", "forces", "generate_mesh", "load_scene", "read_force_csv",
    "read_mesh", "read_pvd", "read_summary", "read_vtu", "read_xdmf", "run",
    "FORCE_CSV_COLUMNS", "SCHEMA_VERSION", "XDMF_SUPPORTED",
]


class NotQuasiStaticWarning(UserWarning):
    """A quasi-static experiment's run failed the quasi-static check (docs/outputs.md): its curve
    is not the cell's equilibrium (`zona run` exits 1 for it). warnings.simplefilter("error",
    zona.NotQuasiStaticWarning) makes it an exception."""


def find_scene(name):
    """The scene file a name ("mouse_oocyte") or path resolves to, as `zona run` looks it up:
    a path as given, then ./scenes, $ZONA_SCENES_DIR, the source tree's scenes/."""
    return _zona.find_scene(os.fspath(name))


def _sets(sets):
    if sets is None:
        return []
    if isinstance(sets, str):
        return [sets]
    if isinstance(sets, dict):
        return [f"{key}={value if isinstance(value, str) else json.dumps(value)}"
                for key, value in sets.items()]
    return [str(s) for s in sets]


def load_scene(name_or_path, sets=None):
    """A scene as a dict, every key resolved and written in SI units ("1.65e+04 Pa"), ready to
    change and pass to zona.run. `sets`: overrides as `zona run --set` takes them, a list of
    "key.path=value" or a dict {"key.path": value}."""
    path = find_scene(name_or_path)
    return json.loads(_zona.load_scene(path, _sets(sets)))


def _scene_text(scene, sets):
    """(JSON text, source file) of a scene given by name, path or dict, validated."""
    if isinstance(scene, dict):
        try:
            text = json.dumps(scene)
        except (TypeError, ValueError) as e:
            raise ZonaError(f"scene dict: not JSON-serialisable: {e}") from None
        return _zona.parse_scene(text, "", _sets(sets)), ""
    path = find_scene(scene)
    return _zona.load_scene(path, _sets(sets)), path


def run(scene="mouse_oocyte", backend="cpu", out=None, progress=None, *, sets=None, threads=0,
        stop_after_puncture=None, frames=None, full_duration=False, progress_interval=0.5):
    """Runs a scene (a name, a path or a dict from load_scene) through the engine's run driver
    and returns a Result.

    backend: "cpu" (default), "cuda" or "auto". out: a folder to write what `zona run` writes
    (force.csv, summary.json, scene.json, frames in the scene's output.format: VTU, XDMF or
    both; no plot), or None to write nothing.
    progress: a callable taking a dict (time_s, end_time_s, wall_s, travel_m, deformation_m,
    force_N, punctured), called about every progress_interval seconds of wall time; returning
    False stops the run (the result says interrupted). sets: overrides ("key.path=value" list
    or dict). threads: CPU threads of the explicit CPU backend and of the static solver (0:
    every core this process may run on). stop_after_puncture: simulated seconds to go on after
    puncture (None: to the scene's end). frames: frames over the run with `out`
    (None: the scene's output.frames). full_duration: as `zona run --full-duration`.

    The GIL is released while the engine steps. Ctrl-C (KeyboardInterrupt) or an exception in
    `progress` stops the run at the next batch of steps; the exception is raised with the
    Result up to there as its `result` attribute (and with `out`, the outputs up to there are
    written). A run that stops early on a failed step raises ZonaError (with `result`).
    """
    text, source = _scene_text(scene, sets)
    if progress is not None and not callable(progress):
        raise TypeError("progress must be callable or None")
    out_dir = "" if out is None else os.fspath(out)
    frame_count = -1 if frames is None else int(frames)
    if not out_dir:
        frame_count = 0
    command = "python: " + shlex.join(sys.argv) if sys.argv and sys.argv[0] else "python"
    raw = _zona.run(text, source, backend, out_dir, progress, float(progress_interval),
                    int(threads), -1.0 if stop_after_puncture is None else float(stop_after_puncture),
                    frame_count, bool(full_duration), command)
    result = Result(raw, out_dir or None)
    error = raw["error"]
    if error is not None:
        error.result = result
        raise error
    if raw["output_error"]:
        e = ZonaError(raw["output_error"])
        e.result = result
        raise e
    if result.stopped_early:
        e = ZonaError("run stopped early: " + result.stop_reason)
        e.result = result
        raise e
    if raw["quasi_static_enforced"] and not raw["quasi_static"]:
        check = result.summary.get("quasi_static_check", {})
        warnings.warn(
            f"{result.summary.get('scene')}: the run was not quasi-static "
            f"({check.get('failed_steps')} steps failed the check; worst imbalance "
            f"{check.get('worst_imbalance')}): its curve is not the cell's equilibrium "
            "(summary['quasi_static'])", NotQuasiStaticWarning, stacklevel=2)
    return result


class Mesh:
    """A tetrahedral mesh: `points` [m] (n x 3), `tets` (m x 4, int32), `region` (m, int32),
    `regions` {name: tag}."""

    def __init__(self, points, tets, region=None, regions=None):
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.tets = np.ascontiguousarray(tets, dtype=np.int32)
        self.region = (np.zeros(len(self.tets), np.int32) if region is None
                       else np.ascontiguousarray(region, dtype=np.int32))
        self.regions = dict(regions or {})

    @classmethod
    def _from(cls, raw):
        return cls(raw["points"], raw["tets"], raw["region"], raw["regions"])

    def write(self, path):
        """Writes .msh (Gmsh 4.1) or .vtu."""
        _zona.write_mesh(os.fspath(path), self.points, self.tets, self.region)

    def __repr__(self):
        return f"Mesh({len(self.points)} vertices, {len(self.tets)} tets, regions {self.regions})"


def read_mesh(path, scale=1.0):
    """A mesh file (.msh, TetGen .node, .vtu) as a Mesh, checked as `zona mesh info` reads it;
    `scale` [m per file unit] (1e-6 for micrometres)."""
    return Mesh._from(_zona.read_mesh(os.fspath(path), float(scale)))


def generate_mesh(scene=None, *, sets=None, diameter=None, vertices=None, edge_length=None,
                  refine_edge_length=None, refine_radius=None, refine_at=None,
                  zona_thickness=None, nucleus_diameter=None, out=None):
    """The cell mesher, as `zona mesh generate`: from a scene (name, path or dict; its
    mesh.generate keys, `vertices` overriding its count) or from a diameter and `vertices` or
    `edge_length`. Lengths in metres or as text with a unit ("56 um"); refine_at is (x, y, z).
    Returns a Mesh; with `out` also writes it (.msh or .vtu)."""
    text, source = ("", "")
    if scene is not None:
        text, source = _scene_text(scene, sets)
    elif diameter is None:
        raise ZonaError("generate_mesh: give a scene or a diameter")
    lengths = {key: value for key, value in (
        ("diameter", diameter), ("edge_length", edge_length),
        ("refine_edge_length", refine_edge_length), ("refine_radius", refine_radius),
        ("zona_thickness", zona_thickness), ("nucleus_diameter", nucleus_diameter))
        if value is not None}
    refine = None if refine_at is None else list(refine_at)
    raw = _zona.generate_mesh(text, source, lengths, refine, int(vertices or 0),
                              "" if out is None else os.fspath(out))
    return Mesh._from(raw)


def forces(rest, deformed, *, model="svk", young=17.9e3, poisson=0.49, formulation="gradient",
           scale=1.0, backend="cpu", out=None):
    """Elastic force on each vertex [N], (n x 3), as `zona forces`: -dW/du of the deformed
    configuration. rest: a Mesh or a mesh file; deformed: an (n x 3) array of positions [m] or
    a file (a mesh, a TetGen .node, or a zona frame .vtu, whose deformed positions are used).
    young [Pa], poisson [-]; scale [m per file unit] for files. With `out`, also writes the
    CSV `zona forces` writes (vertex,fx,fy,fz)."""
    mesh = rest if isinstance(rest, Mesh) else read_mesh(rest, scale)
    if isinstance(deformed, (str, os.PathLike)):
        positions = _zona.read_positions(os.fspath(deformed), float(scale))
    else:
        positions = np.ascontiguousarray(deformed, dtype=np.float64)
    f = _zona.elastic_forces(mesh.points, mesh.tets, mesh.region, positions, model, formulation,
                             float(young), float(poisson), backend)
    if out is not None:
        table = np.column_stack([np.arange(len(f)), f])
        np.savetxt(os.fspath(out), table, fmt=["%d", "%.17g", "%.17g", "%.17g"], delimiter=",",
                   header="vertex,fx,fy,fz", comments="")
    return f
