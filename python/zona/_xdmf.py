"""Reader of zona's XDMF time series (output.format "xdmf": frames.xdmf + frames.h5;
docs/outputs.md): the .xdmf's Temporal collection says which datasets of the .h5 make each frame;
h5py reads them. Frames come back as the Vtu objects read_vtu gives, so code written for the VTU
frames reads these unchanged. Errors are zona.ZonaError, one line naming the file."""

import os
import xml.etree.ElementTree as ElementTree

import numpy as np

from ._readers import Vtu
from ._zona import ZonaError


def _h5py(path):
    try:
        import h5py
    except ImportError:
        raise ZonaError(f"{path}: reading an XDMF series needs h5py (python/requirements.txt; "
                        "bash scripts/setup.sh installs it)") from None
    return h5py


def _shaped(values, components):
    """A point or cell array shaped as read_vtu shapes it: (n), (n x c), tensors (n x 3 x 3)."""
    if components == 9:
        return values.reshape(-1, 3, 3)
    if components == 1:
        return values.reshape(-1)
    return values.reshape(-1, components)


class _Grid:
    """One frame's grid of the .xdmf: its time, the DataItems of its geometry and topology, its
    attributes and Information elements (names and values as text)."""

    def __init__(self, element, path, number):
        def fail(what):
            raise ZonaError(f"{path}: frame {number}: {what}")

        time = element.find("Time")
        if time is None or time.get("Value") is None:
            fail("no <Time Value=...>")
        try:
            self.time = float(time.get("Value"))
        except ValueError:
            fail(f"Time '{time.get('Value')}' is not a number")
        self.geometry = element.find("Geometry/DataItem")
        topology = element.find("Topology")
        if self.geometry is None or topology is None or topology.find("DataItem") is None:
            fail("no Geometry or Topology DataItem")
        kind = topology.get("TopologyType") or topology.get("Type")
        if kind != "Tetrahedron":
            fail(f"topology '{kind}' (zona writes Tetrahedron)")
        self.topology = topology.find("DataItem")
        self.attributes = []
        for attribute in element.findall("Attribute"):
            item, center = attribute.find("DataItem"), attribute.get("Center")
            if item is None or center not in ("Node", "Cell"):
                fail(f"attribute '{attribute.get('Name')}' needs a DataItem and Center Node or Cell")
            self.attributes.append((attribute.get("Name"), center, item))
        self.information = {i.get("Name"): i.get("Value") for i in element.findall("Information")}


class XdmfSeries:
    """zona's XDMF time series. `times` [s] (one per frame), `points` the rest positions [m]
    (n x 3), `tets` (m x 4, int32), `regions` {name: tag}, `note` (the files' note); len(series)
    frames; series[k] (negative k from the end) and iteration give each frame as a Vtu: `points`
    (rest), `point_data` (displacement, contact, stress and strain as (n x 3 x 3), von_mises),
    `cell_data` (green_strain, von_mises_stress, region), `field_data` (TimeValue,
    points_at_rest, region:NAME, as a VTU frame has them), `time`, `deformed_points`."""

    def __init__(self, path):
        self.path = path
        self.folder = os.path.dirname(os.path.abspath(path))
        try:
            root = ElementTree.parse(path).getroot()
        except OSError as e:
            raise ZonaError(f"{path}: cannot open: {e.strerror}") from None
        except ElementTree.ParseError as e:
            raise ZonaError(f"{path}:{e.position[0]}: not XML: {e.msg}") from None
        if root.tag != "Xdmf" or not str(root.get("Version", "")).startswith("3"):
            raise ZonaError(f"{path}: not an XDMF 3 file (<Xdmf Version=\"3.0\">)")
        collection = None
        for grid in root.iterfind("Domain/Grid"):
            if grid.get("GridType") == "Collection" and grid.get("CollectionType") == "Temporal":
                collection = grid
        if collection is None:
            raise ZonaError(f"{path}: no Temporal collection (Grid CollectionType=\"Temporal\")")
        self._grids = [_Grid(g, path, k) for k, g in enumerate(collection.findall("Grid"))]
        self.times = np.array([g.time for g in self._grids], dtype=np.float64)
        self._cache = {}  # (file, dataset) -> array: the mesh is shared by every grid
        self.note = ""
        if self._grids:
            first = self._grids[0]
            self.points = self._read(first.geometry, cache=True).reshape(-1, 3)
            self.tets = self._read(first.topology, cache=True).reshape(-1, 4).astype(np.int32)
            self.regions = {name[len("region:"):]: int(float(value))
                            for name, value in first.information.items()
                            if name and name.startswith("region:")}
        else:
            self.points, self.tets, self.regions = np.zeros((0, 3)), np.zeros((0, 4), np.int32), {}

    def _read(self, item, cache=False):
        """The array a DataItem names ("file.h5:/path"), checked against its Dimensions."""
        if item.get("Format") != "HDF":
            raise ZonaError(f"{self.path}: DataItem format '{item.get('Format')}' (zona writes HDF)")
        text = (item.text or "").strip()
        file, sep, dataset = text.rpartition(":")
        if not sep or not file or not dataset.startswith("/"):
            raise ZonaError(f"{self.path}: DataItem '{text}' is not FILE.h5:/dataset")
        key = (file, dataset)
        if key in self._cache:
            return self._cache[key]
        h5_path = os.path.join(self.folder, file)
        h5py = _h5py(self.path)
        try:
            with h5py.File(h5_path, "r") as h5:
                if dataset not in h5 or not isinstance(h5[dataset], h5py.Dataset):
                    raise ZonaError(f"{h5_path}: no dataset {dataset} (named by {self.path})")
                values = h5[dataset][()]
                if dataset == "/mesh/points" and not self.note:
                    note = h5.attrs.get("note", b"")
                    self.note = note.decode() if isinstance(note, bytes) else str(note)
        except OSError as e:
            raise ZonaError(f"{h5_path}: cannot read as HDF5: {e}") from None
        try:
            dims = [int(d) for d in item.get("Dimensions", "").split()]
        except ValueError:
            raise ZonaError(f"{self.path}: Dimensions '{item.get('Dimensions')}' of {dataset}") from None
        if int(np.prod(dims)) != values.size:
            raise ZonaError(f"{h5_path}: {dataset} holds {values.size} values, the .xdmf says "
                            f"{' x '.join(map(str, dims))}")
        values = values.reshape(dims)
        if cache:
            self._cache[key] = values
        return values

    def __len__(self):
        return len(self._grids)

    def __getitem__(self, k):
        grid = self._grids[k]
        n, m = len(self.points), len(self.tets)
        data = {"Node": {}, "Cell": {}}
        for name, center, item in grid.attributes:
            values = self._read(item, cache=item.text.strip().endswith(":/mesh/region"))
            rows = n if center == "Node" else m
            if values.shape[0] != rows:
                raise ZonaError(f"{self.path}: attribute '{name}' has {values.shape[0]} rows, "
                                f"expected {rows}")
            components = int(values.size // rows) if rows else 1
            data[center][name] = _shaped(values, components)
        field = {"TimeValue": np.array([grid.time])}
        for name, value in grid.information.items():
            try:
                field[name] = np.array([float(value)])
            except (TypeError, ValueError):
                continue  # text, not an array of the VTU's field data
        raw = {"points": self.points, "tets": self.tets, "regions": self.regions,
               "point_data": data["Node"], "cell_data": data["Cell"], "field_data": field}
        index = k if k >= 0 else len(self._grids) + k
        return Vtu(raw, f"{self.path}[{index}]")

    def __iter__(self):
        return (self[k] for k in range(len(self)))

    def __repr__(self):
        return (f"XdmfSeries({self.path!r}: {len(self)} frames, {len(self.points)} points, "
                f"{len(self.tets)} tets)")


def read_xdmf(path):
    """zona's XDMF time series (frames.xdmf + frames.h5 beside it) as an XdmfSeries."""
    return XdmfSeries(os.fspath(path))
