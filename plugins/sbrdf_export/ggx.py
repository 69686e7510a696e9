"""The GGX conversion the MaterialX, USD and Mitsuba exporters share (:mod:`sbrdf_lib.convert`).

The conversion target is the installed ``cook-torrance`` model with GGX
facets, found through the registry given to ``bind`` (plugins never import
each other).  Every converting exporter stores, beside the format's maps,
``conversion_error`` (the per-texel held-out relative error, also the Export
node's ``error``) and ``flagged`` (1 where it is above ``flag_error``), and
writes both as files: ``conversion_error.exr`` and ``flagged.png``
(:func:`write_error_files`).
"""

from __future__ import annotations

import os

import numpy as np


def with_flags(maps: dict, flag_error: float) -> dict:
    """``maps`` plus ``conversion_error`` (= ``error``) and ``flagged`` (1.0 where error > ``flag_error``), lazily."""
    error = maps["error"]
    return {**maps, "conversion_error": error, "flagged": (error > flag_error).astype(np.float32)}


def write_error_files(directory: str, maps: dict, flag_error: float, rows_bottom_up: bool = False) -> tuple[list, dict]:
    """``conversion_error.exr`` and ``flagged.png`` (255 where flagged) from the stored maps; ``(files, attrs)``.

    Rows follow the format's texture convention (``rows_bottom_up`` for USD and MaterialX).
    """
    from sbrdf_core.io import write_exr, write_png

    if "conversion_error" not in maps:
        return [], {}
    e = np.asarray(maps["conversion_error"], np.float32)
    flagged = np.asarray(maps["flagged"], np.float32)[..., 0] > 0.5
    order = slice(None, None, -1) if rows_bottom_up else slice(None)
    write_exr(os.path.join(directory, "conversion_error.exr"), np.repeat(e[order], 3, axis=-1))
    write_png(os.path.join(directory, "flagged.png"), (flagged[order] * 255).astype(np.uint8))
    finite = e[np.isfinite(e)]
    attrs = {"flag_error": float(flag_error), "flagged": int(flagged.sum()),
             "flagged_fraction": float(flagged.mean()) if flagged.size else 0.0,
             "conversion_error_median": float(np.median(finite)) if finite.size else None}
    return ["conversion_error.exr", "flagged.png"], attrs


class GGXConverting:
    """Base of the exporters that refit to GGX: ``bind`` keeps the registry for the conversion target."""

    registry = None
    starts = 1
    iterations = 8
    flag_error = 0.25
    max_theta_deg = 70.0

    def bind(self, registry) -> None:
        self.registry = registry

    def _ggx(self):
        from sbrdf_lib.convert import ggx_model

        return ggx_model(self.registry)

    def ggx_maps(self, material, grazing: bool = True) -> dict:
        """Lazy :data:`sbrdf_lib.convert.GGX_MAPS` (V, U, C) of the GGX fit, with the flags (:func:`with_flags`).

        ``grazing`` False: the specular weight is held at 1 (a format whose Fresnel always reaches 1 at grazing).
        """
        from sbrdf_lib.convert import to_ggx_blocks

        return with_flags(to_ggx_blocks(material.model, material.params, self._ggx(), starts=self.starts,
                                        iterations=self.iterations, grazing=grazing, flag_error=self.flag_error,
                                        max_theta_deg=self.max_theta_deg),
                          self.flag_error)

    def gltf_maps(self, material) -> dict:
        """Lazy glTF metallic-roughness maps (:data:`sbrdf_lib.convert.GLTF_MAPS`), ``error`` and the flags."""
        from sbrdf_lib.convert import to_gltf_pbr_blocks

        return with_flags(to_gltf_pbr_blocks(material.model, material.params, self._ggx(), starts=self.starts,
                                             iterations=self.iterations, flag_error=self.flag_error,
                                             max_theta_deg=self.max_theta_deg), self.flag_error)

    def ggx_uniform(self, model, params: dict) -> dict:
        """The GGX fit of one uniform material (a scene's ``{model, params}``): ρ_d, F0c, s, α (C,) and its error."""
        from sbrdf_lib.convert import to_ggx

        flat = {p.name: np.broadcast_to(np.asarray(params.get(p.name, p.default), np.float64).reshape(1, -1), (1, p.channels))
                for p in model.parameters}
        r = to_ggx(model, flat, self._ggx(), starts=self.starts, iterations=self.iterations,
                   max_theta_deg=self.max_theta_deg)
        keys = ("rho_d", "f0", "alpha", "specular", "specular_color")
        return {k: np.asarray(r[k][0], np.float64) for k in keys} | {"error": float(r["error"][0])}
