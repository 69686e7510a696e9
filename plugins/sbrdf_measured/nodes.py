"""Node kinds: ``MerlFromModel`` (a MERL-format file from any installed model) and ``MeasuredBRDF``
(a MERL, ASTM or UTIA file -> a 1 × 1-texel SampledReflectance that ``Fit`` takes).

Why ``MerlFromModel``: graphs and tests must run on data they make, and the
MERL database itself cannot ship here; writing a file in the exact format from
a known analytic BRDF exercises the same reader a downloaded file goes through
(``MeasuredBRDF`` reads the written ``.binary`` file, not the stored array).

SampledReflectance stores positions, not directions: as in ``MeasuredTable``
(plugins/sbrdf_tables), the one texel's centre is the origin and each
direction pair is placed at ``distance_mm`` along ω_i and ω_o, so the Fit
node derives exactly the sampled directions.

Which directions (``directions``):

- ``fibonacci``: ``incident`` × ``exitant`` Fibonacci-spiral directions up to
  ``max_theta_deg`` (every incident direction with every exitant one; the
  exitant spiral is turned by 2 rad so no pair is exactly mirrored by
  construction), looked up with ``interpolation``;
- ``bins`` (MERL only): the table's own entries, every ``stride``-th along
  (θh, θd, φd), at their node directions (φh = 0; the material is isotropic),
  each sample exactly one stored value; missing entries are invalid samples.

ASTM and UTIA files are always sampled at their own direction pairs.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from sbrdf_core.artifacts import ArraySpec, ArtifactKind, SampledReflectance
from sbrdf_core.geometry import fibonacci_hemisphere
from sbrdf_core.nodes.base import BuildContext, NodeKind, Output, Port
from sbrdf_core.params import Param

from .declarations import MERL_DIMS

MERL_FILE = ArtifactKind(
    "MerlFile",
    1,
    "A BRDF tabulated in the MERL binary format (material.binary beside the arrays; attrs: file, path, dims, "
    "model, model_config, params).",
    (ArraySpec("table", "ABDC", "float64", "f_r at the table's nodes (theta_h, theta_d, phi_d, RGB), sr^-1; NaN "
               "where the node pair is below the horizon (stored as -1 in the file)"),),
)

FILE_NAME = "material.binary"


class MerlFromModel(NodeKind):
    name = "MerlFromModel"
    doc = ("Tabulate an installed BRDF model with one parameter set in the MERL binary format (a file beside the "
           "arrays), for graphs that import MERL data they make themselves.")
    output = MERL_FILE
    params = (
        Param("model", "str", "cook-torrance", "BRDF model to tabulate", extra={"plugin_category": "brdf-model"}),
        Param("model_params", "dict", {}, "configuration of that model", extra={"params_of": "model"}),
        Param("params", "dict", {}, "the model's parameter values (scalars or RGB triples); others at their defaults",
              extra={"model_values_of": ("model", "model_params")}),
        Param("dims", "list", list(MERL_DIMS), "table dimensions [theta_h, theta_d, phi_d]; the database's are "
              "[90, 90, 180]", length=3, item="int", bounds=(2, 1000)),
    )

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        p = ctx.params
        model = ctx.plugins().create("brdf-model", p["model"], dict(p["model_params"]))
        values = model.defaults(1)
        for name, v in p["params"].items():
            if name not in values:
                known = ", ".join(q.name for q in model.parameters)
                raise ValueError(f"MerlFromModel: {p['model']!r} has no parameter {name!r}; its parameters: {known}")
            values[name] = np.broadcast_to(np.asarray(v, np.float64).reshape(-1), values[name].shape[1:])[None].copy()
        dims = tuple(int(n) for n in p["dims"])
        rows = max(1, min(dims[0], 10))

        from .merl import tabulate, write_merl

        def block(index, block_info=None):
            lo, hi = block_info[0]["array-location"][0]
            f, ok = tabulate(model, values, dims, (lo, hi))
            return np.where(ok[..., None], f, np.nan)

        index = da.zeros(dims[0], chunks=rows, dtype=np.int8)
        table = da.map_blocks(block, index, new_axis=[1, 2, 3], chunks=(index.chunks[0], (dims[1],), (dims[2],), (3,)),
                              dtype=np.float64, name=ctx.key("merl"))

        def finalize(out):
            t = out.read("table")
            path = os.path.join(out.url, FILE_NAME)
            write_merl(path, np.nan_to_num(t), np.isfinite(t).all(axis=-1))
            return {"files": [FILE_NAME], "path": path, "bytes": os.path.getsize(path)}

        return Output(arrays={"table": table}, attrs={
            "dims": list(dims), "model": model.name, "model_config": dict(p["model_params"]),
            "params": {k: np.asarray(v).ravel().tolist() for k, v in values.items()}}, finalize=finalize)


class MeasuredBRDF(NodeKind):
    name = "MeasuredBRDF"
    doc = ("Read a measured BRDF (MERL .binary, ASTM E1392 text or a UTIA anisotropic .bin) into a 1x1-texel "
           "SampledReflectance for Fit.")
    inputs = (Port("table", (MERL_FILE,), "a MerlFile artifact (its material.binary is read) instead of path",
                   optional=True),)
    output = SampledReflectance
    params = (
        Param("path", "str", None, "MERL .binary, ASTM .astm or UTIA .bin file, relative to the graph file (or give "
              "in: table)",
              nullable=True, extra={"path": True}),
        Param("format", "str", "auto", "file format; auto: .astm is ASTM, .bin UTIA, anything else MERL",
              choices=("auto", "merl", "astm", "utia")),
        Param("directions", "str", "fibonacci", "MERL sampling: fibonacci incident x exitant pairs, or the table's "
              "own bins", choices=("fibonacci", "bins")),
        Param("incident", "int", 32, "fibonacci: incident directions", bounds=(1, 4096)),
        Param("exitant", "int", 256, "fibonacci: exitant directions per incident one", bounds=(1, 65536)),
        Param("max_theta_deg", "float", 85.0, "fibonacci: largest polar angle of both directions",
              bounds=(1.0, 89.9), unit="deg"),
        Param("stride", "list", [3, 3, 6], "bins: every n-th entry along theta_h, theta_d, phi_d", length=3,
              item="int", bounds=(1, 180)),
        Param("interpolation", "str", "trilinear", "fibonacci: table lookup, trilinear between the entries' nodes, or "
              "nearest (MERL's BRDFRead.cpp: every sample a stored value, constant over each bin)",
              choices=("trilinear", "nearest")),
        Param("distance_mm", "float", 1e6, "distance of the light/camera positions standing for the directions",
              bounds=(1.0, None), unit="mm"),
    )

    @staticmethod
    def check_params(params) -> list[tuple[str, str]]:
        """A file given by path is opened when the graph is validated, so a bad file fails before anything runs."""
        from .astm import AstmError
        from .merl import MerlError
        from .utia import UtiaError

        path = params.get("path")
        if path is None:
            return []
        try:
            _read(path, params.get("format", "auto"))
        except (MerlError, AstmError, UtiaError) as e:
            return [("path", str(e))]
        except UnicodeDecodeError as e:
            return [("path", f"{path}: not UTF-8 text (byte offset {e.start})")]
        return []

    @classmethod
    def fingerprint(cls, ctx: BuildContext) -> str:
        """The file's size and modification time: a replaced file is re-read."""
        path = ctx.params.get("path")
        if path and os.path.exists(path):
            st = os.stat(path)
            return f"{st.st_size}:{st.st_mtime_ns}"
        return ""

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        p = ctx.params
        art = ctx.inputs.get("table")
        if (art is None) == (p["path"] is None):
            raise ValueError(f"MeasuredBRDF {ctx.node!r}: give either path: (a file) or in: {{table: ...}}, not "
                             f"{'both' if art is not None else 'neither'}")
        path = os.path.join(art.url, FILE_NAME) if art is not None else p["path"]
        fmt = "merl" if art is not None else p["format"]
        t0 = time.perf_counter()
        table, fmt = _read(path, fmt)
        import_s = time.perf_counter() - t0
        info: dict = {"path": str(path), "format": fmt, "import_s": import_s}
        if fmt in ("astm", "utia"):  # samples at the file's own direction pairs
            wi, wo, f, ok = table.wi, table.wo, table.f_r, np.ones(len(table), bool)
            ok &= (wi[:, 2] > 0) & (wo[:, 2] > 0) & np.isfinite(f).all(axis=1)
            info.update(channels=list(table.channels), entries=len(table))
        elif p["directions"] == "bins":
            wi, wo, (i, j, k) = table.node_directions(tuple(p["stride"]))
            f, ok = table.f_r[i, j, k], table.measured[i, j, k] & (wi[:, 2] > 0) & (wo[:, 2] > 0)
            info.update(dims=list(table.dims), sampling="bins", stride=list(p["stride"]))
        else:
            li = fibonacci_hemisphere(p["incident"], p["max_theta_deg"])
            lo = fibonacci_hemisphere(p["exitant"], p["max_theta_deg"], offset=2.0)
            wi = np.repeat(li, len(lo), axis=0)
            wo = np.tile(lo, (len(li), 1))
            f, ok = table.lookup(wi, wo, p["interpolation"])
            info.update(dims=list(table.dims), sampling="fibonacci", interpolation=p["interpolation"],
                        measured_fraction=float(table.measured.mean()))
        f = np.where(ok[:, None], f, 0.0)
        d = p["distance_mm"]
        arrays = {"f_r": da.from_array(f[None, None].astype(np.float32)), "valid": da.from_array(ok[None, None]),
                  "light_pos": da.from_array(wi * d), "camera_pos": da.from_array(wo * d)}
        info.update(samples=int(len(ok)), valid=int(ok.sum()))
        return Output(arrays=arrays, attrs={
            "texels": [1, 1], "size_mm": [1e-3, 1e-3], "light": {"type": "directional", "intensity": 1.0}, "tile": 1,
            "measured": info})


def _read(path, fmt: str):
    """``(table, format)`` of a MERL, ASTM or UTIA file."""
    from .astm import read_astm
    from .merl import read_merl
    from .utia import read_utia

    if fmt == "auto":
        fmt = {".astm": "astm", ".bin": "utia"}.get(Path(path).suffix.lower(), "merl")
    return {"astm": read_astm, "utia": read_utia}.get(fmt, read_merl)(path), fmt
