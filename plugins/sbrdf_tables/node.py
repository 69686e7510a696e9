"""MeasuredTable: a gonioreflectometer table as a 1 × 1-texel SampledReflectance, so ``Fit`` applies.

SampledReflectance stores light and camera *positions*; per-texel directions
are derived from them (sbrdf_core.geometry.tile_directions).  The table's
directions are placed at ``distance_mm`` (1e6 mm) along ω_i and ω_o from the
single texel, whose centre is the origin: the derived directions are the
table's exactly (to float64 round-off).  Transmission entries put the camera
below the plane (z < 0); the geometry code derives such directions unchanged
and the kurt-transmissive model evaluates them, while models without
transmission return 0 there (their ``above_horizon`` test).

f_r = p / |cos θ_o| in all three channels (the tables are single-channel);
``valid`` is false for unmeasured entries and at θ_o = 90°, where the BSDF is
undefined.  Measured zeros stay valid samples of value 0; the grid-search
fitter leaves them out of its metric as the thesis does.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.artifacts import SampledReflectance
from sbrdf_core.nodes.base import BuildContext, NodeKind, Output
from sbrdf_core.params import Param


def table_arrays(table, distance_mm: float = 1e6) -> dict[str, np.ndarray]:
    """``f_r (1, 1, P, 3)``, ``valid (1, 1, P)``, ``light_pos``, ``camera_pos`` ``(P, 3)`` of a table."""
    f = table.bsdf()
    valid = np.isfinite(f)
    f_r = np.repeat(np.where(valid, f, 0.0)[None, None, :, None], 3, axis=-1).astype(np.float32)
    return {"f_r": f_r, "valid": valid[None, None, :], "light_pos": table.wi * distance_mm,
            "camera_pos": table.wo * distance_mm}


class MeasuredTableNode(NodeKind):
    name = "MeasuredTable"
    doc = "Read a gonioreflectometer transfer-probability table (docs/measured-tables.md) into a 1x1 SampledReflectance."
    output = SampledReflectance
    params = (
        Param("path", "str", None, "table file (CSV: theta_i, phi_i, theta_o, phi_o, p or bsdf), relative to the graph "
              "file", extra={"path": True}),
        Param("distance_mm", "float", 1e6, "distance of the light/camera positions standing for the directions",
              bounds=(1.0, None), unit="mm"),
    )

    @staticmethod
    def check_params(params) -> list[tuple[str, str]]:
        """The table file is read when the graph is validated, so a bad row is reported before anything runs."""
        from .table import TableError, read_table

        if params.get("path") is None:
            return [("path", "a MeasuredTable needs 'path': the table file")]
        try:
            read_table(params["path"])
        except TableError as e:
            return [("path", str(e))]
        except UnicodeDecodeError as e:
            return [("path", f"{params['path']}: not UTF-8 text (byte 0x{e.object[e.start]:02x} at offset {e.start})")]
        return []

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        from .table import read_table

        table = read_table(ctx.params["path"])
        arrays = table_arrays(table, ctx.params["distance_mm"])
        integrals = table.integrals()
        out = {k: da.from_array(v) for k, v in arrays.items()}
        return Output(arrays=out, attrs={
            "texels": [1, 1], "size_mm": [1e-3, 1e-3], "light": {"type": "directional", "intensity": 1.0}, "tile": 1,
            "table": {"path": str(ctx.params["path"]), "entries": len(table), "measured": int(table.measured.sum()),
                      "incident_directions": int(len(integrals["theta_i"])),
                      "mean_reflectance": float(integrals["reflectance"].mean()),
                      "mean_transmittance": float(integrals["transmittance"].mean())},
        })
