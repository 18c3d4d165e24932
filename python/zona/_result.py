"""zona.Result: what zona.run returns (the curve, the summary, the final fields)."""

import json

from ._readers import Columns


class Result:
    """A run's result.

    - `columns`: force.csv's columns as numpy arrays (docs/outputs.md), also as attributes of
      the result itself: `result.deformation_m`, `result.force_N`, ...
    - `summary`: summary.json as a dict; `puncture` (its "puncture": whether and where the
      membrane gave way), `quasi_static` (True, False, or None when nothing was judged),
      `interrupted`. (`result.punctured` is force.csv's column, one flag per row.)
    - final state, SI units: `rest_positions` (n x 3), `displacement` (n x 3),
      `deformed_positions`, `stress` (n x 3 x 3, Cauchy, per vertex), `strain` (n x 3 x 3,
      Green-Lagrange), `von_mises` (n), `contact` (n), `tets` (m x 4), `tet_region` (m),
      `regions` {name: tag}; `point_fields` and `cell_fields` hold every array a VTU frame has.
      They are views into the engine's memory (not copies), kept alive by the arrays.
    - `scene`: the scene as run (a dict, every key resolved); `out`: the output folder or None;
      `notes`: setup notes, one line each.
    """

    def __init__(self, raw, out=None):
        self.columns = Columns(raw["columns"], schema_version=None)
        self.columns["punctured"] = self.columns["punctured"].view(bool)
        self.summary = json.loads(raw["summary"])
        self.columns.schema_version = self.summary.get("schema_version")
        self.scene = json.loads(raw["scene"])
        self.interrupted = bool(raw["interrupted"])
        self.stopped_early = bool(raw["stopped_early"])
        self.stop_reason = raw["stop_reason"]
        self.notes = list(raw["notes"])
        self.out = out
        self.point_fields = raw["point_fields"]
        self.cell_fields = raw["cell_fields"]
        self.rest_positions = raw["rest_positions"]
        self.tets = raw["tets"]
        self.tet_region = raw["tet_region"]
        self.regions = raw["regions"]

    @property
    def puncture(self):
        """summary["puncture"]: punctured, criterion, threshold, and when punctured time_s,
        needle_travel_m, deformation_m, force_N, ..."""
        return self.summary["puncture"]

    @property
    def quasi_static(self):
        """summary["quasi_static"]: True, False, or None (nothing judged)."""
        return self.summary["quasi_static"]

    @property
    def displacement(self):
        return self.point_fields["displacement"]

    @property
    def deformed_positions(self):
        return self.rest_positions + self.point_fields["displacement"]

    @property
    def stress(self):
        return self.point_fields["stress"]

    @property
    def strain(self):
        return self.point_fields["strain"]

    @property
    def von_mises(self):
        return self.point_fields["von_mises"]

    @property
    def contact(self):
        return self.point_fields["contact"]

    def __getattr__(self, name):
        # Column names as attributes (only reached when no attribute has the name).
        columns = self.__dict__.get("columns")
        if columns is not None and name in columns:
            return columns[name]
        raise AttributeError(f"'Result' has no attribute or column '{name}'")

    def __dir__(self):
        return list(super().__dir__()) + list(self.columns)

    def __repr__(self):
        p = self.puncture
        what = (f"punctured at {p['deformation_m'] * 1e6:.2f} um, {p['force_N'] * 1e6:.3f} uN"
                if p.get("punctured") else "no puncture")
        return (f"Result({self.summary.get('scene')!r}: {len(self.columns['time_s'])} samples, "
                f"{what}, peak {self.summary.get('peak_force_N', 0) * 1e6:.3f} uN"
                f"{', interrupted' if self.interrupted else ''})")
