"""Readers of what `zona run` writes: force.csv, summary.json, VTU frames and their .pvd series
(docs/outputs.md). Errors are zona.ZonaError with one line naming the file (and line)."""

import json
import os
import re
import xml.etree.ElementTree as ElementTree
from typing import NamedTuple

import numpy as np

from . import _zona
from ._zona import ZonaError

# Columns that are not float64: the contact counts and the puncture flag.
_INT_COLUMNS = {"contacts": np.int32, "holding_contacts": np.int32}
_BOOL_COLUMNS = {"punctured"}


class Columns(dict):
    """force.csv's columns by name (time_s, force_N, ...), each a 1-D numpy array; also readable
    as attributes (columns.force_N). `schema_version` is the file's schema (None when unknown)."""

    def __init__(self, columns=(), schema_version=None):
        super().__init__(columns)
        self.schema_version = schema_version

    def __getattr__(self, name):
        try:
            return self[name]
        except KeyError:
            raise AttributeError(f"no column '{name}' (columns: {', '.join(self)})") from None

    def __dir__(self):
        return list(super().__dir__()) + list(self)


def _typed(name, values):
    if name in _BOOL_COLUMNS:
        return values != 0
    if name in _INT_COLUMNS:
        return values.astype(_INT_COLUMNS[name])
    return values


def read_force_csv(path):
    """A force.csv as Columns: one array per column, in the file's order. Lines starting with
    '#' are comments (the first one names the schema version)."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except OSError as e:
        raise ZonaError(f"{path}: cannot open: {e.strerror}") from None
    except UnicodeDecodeError:
        raise ZonaError(f"{path}: not a text file") from None
    schema = None
    header = None
    rows = []
    for number, line in enumerate(lines, start=1):
        if line.startswith("#"):
            match = re.match(r"# zona force\.csv schema (\d+)", line)
            if match and header is None:
                schema = int(match.group(1))
            continue
        if not line.strip():
            continue
        if header is None:
            header = line.split(",")
            continue
        fields = line.split(",")
        if len(fields) != len(header):
            raise ZonaError(f"{path}:{number}: {len(fields)} values for {len(header)} columns")
        try:
            rows.append([float(x) for x in fields])
        except ValueError:
            raise ZonaError(f"{path}:{number}: a value is not a number") from None
    if header is None:
        raise ZonaError(f"{path}: no header line (expected {','.join(_zona.force_csv_columns[:3])},...)")
    data = np.array(rows, dtype=np.float64).reshape(len(rows), len(header))
    return Columns(((name, _typed(name, data[:, i].copy())) for i, name in enumerate(header)),
                   schema_version=schema)


def read_summary(path):
    """A summary.json as a dict (docs/outputs.md lists its keys)."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            summary = json.load(f)
    except OSError as e:
        raise ZonaError(f"{path}: cannot open: {e.strerror}") from None
    except json.JSONDecodeError as e:
        raise ZonaError(f"{path}:{e.lineno}: not JSON: {e.msg}") from None
    except UnicodeDecodeError:
        raise ZonaError(f"{path}: not a text file") from None
    if not isinstance(summary, dict) or "schema_version" not in summary:
        raise ZonaError(f"{path}: not a zona summary (no schema_version)")
    return summary


class Vtu:
    """A .vtu of zona's with all its arrays. `points` [m] as written (the rest positions in a
    frame), `tets` (m x 4), `point_data` and `cell_data` by name (tensors as (n x 3 x 3)),
    `field_data` by name (1-D), `regions` {name: tag}."""

    def __init__(self, raw, path):
        self.path = path
        self.points = raw["points"]
        self.tets = raw["tets"]
        self.regions = raw["regions"]
        self.point_data = raw["point_data"]
        self.cell_data = raw["cell_data"]
        self.field_data = raw["field_data"]

    @property
    def time(self):
        """The frame's simulated time [s] (field array TimeValue), or None."""
        value = self.field_data.get("TimeValue")
        return float(value[0]) if value is not None and len(value) else None

    @property
    def points_at_rest(self):
        """True for a zona frame: the points are the rest positions (docs/outputs.md)."""
        value = self.field_data.get("points_at_rest")
        return bool(value is not None and len(value) and value[0] == 1)

    @property
    def deformed_points(self):
        """Deformed positions [m]: points + displacement for a frame at rest, else the points."""
        displacement = self.point_data.get("displacement")
        if self.points_at_rest and displacement is not None:
            return self.points + displacement
        return self.points

    def __repr__(self):
        return (f"Vtu({self.path!r}: {len(self.points)} points, {len(self.tets)} tets, point "
                f"{sorted(self.point_data)}, cell {sorted(self.cell_data)})")


def read_vtu(path):
    """A .vtu (zona's frames, `zona mesh convert` output) with every array, as a Vtu."""
    path = os.fspath(path)
    return Vtu(_zona.read_vtu(path), path)


class Frame(NamedTuple):
    """One entry of a .pvd series: simulated time [s] and the .vtu's path."""

    time: float
    path: str

    def read(self):
        """The frame's Vtu."""
        return read_vtu(self.path)


def read_pvd(path):
    """A ParaView .pvd series as a list of Frame(time, path), in file order; paths are resolved
    against the .pvd's folder."""
    path = os.fspath(path)
    try:
        root = ElementTree.parse(path).getroot()
    except OSError as e:
        raise ZonaError(f"{path}: cannot open: {e.strerror}") from None
    except ElementTree.ParseError as e:
        raise ZonaError(f"{path}:{e.position[0]}: not XML: {e.msg}") from None
    collection = root.find("Collection")
    if root.tag != "VTKFile" or root.get("type") != "Collection" or collection is None:
        raise ZonaError(f"{path}: not a .pvd collection (VTKFile type=\"Collection\")")
    folder = os.path.dirname(path)
    frames = []
    for number, dataset in enumerate(collection.findall("DataSet")):
        file, time = dataset.get("file"), dataset.get("timestep")
        if file is None or time is None:
            raise ZonaError(f"{path}: DataSet {number} needs file and timestep")
        try:
            frames.append(Frame(float(time), os.path.join(folder, file)))
        except ValueError:
            raise ZonaError(f"{path}: DataSet {number}: timestep '{time}' is not a number") from None
    return frames
