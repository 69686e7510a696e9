"""The GGX conversion the MaterialX, USD and Mitsuba exporters share (:mod:`sbrdf_lib.convert`).

The conversion target is the installed ``cook-torrance`` model with GGX
facets, found through the registry given to ``bind`` (plugins never import
each other).
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.params import Param

STARTS = Param("starts", "int", 2, "LM starts of the per-texel GGX refit", bounds=(1, 8))
ITERATIONS = Param("iterations", "int", 50, "LM iterations of the per-texel GGX refit", bounds=(1, 1000))


class GGXConverting:
    """Base of the exporters that refit to GGX: ``bind`` keeps the registry for the conversion target."""

    registry = None
    starts = 2
    iterations = 50

    def bind(self, registry) -> None:
        self.registry = registry

    def _ggx(self):
        from sbrdf_lib.convert import ggx_model

        return ggx_model(self.registry)

    def ggx_maps(self, material) -> dict:
        """Lazy ``{"rho_d", "f0", "alpha", "error"}`` (V, U, C) of the GGX fit (cook-torrance reading)."""
        from sbrdf_lib.convert import to_ggx_blocks

        return to_ggx_blocks(material.model, material.params, self._ggx(), starts=self.starts,
                             iterations=self.iterations)

    def gltf_maps(self, material) -> dict:
        """Lazy glTF metallic-roughness maps (:data:`sbrdf_lib.convert.GLTF_MAPS`) and ``error``."""
        from sbrdf_lib.convert import to_gltf_pbr_blocks

        return to_gltf_pbr_blocks(material.model, material.params, self._ggx(), starts=self.starts,
                                  iterations=self.iterations)

    def ggx_uniform(self, model, params: dict) -> dict:
        """The GGX fit of one uniform material (a scene's ``{model, params}``): ``{"rho_d", "f0", "alpha"}`` (C,)."""
        from sbrdf_lib.convert import to_ggx

        flat = {p.name: np.broadcast_to(np.asarray(params.get(p.name, p.default), np.float64).reshape(1, -1), (1, p.channels))
                for p in model.parameters}
        r = to_ggx(model, flat, self._ggx(), starts=self.starts, iterations=self.iterations)
        return {k: np.asarray(r[k][0], np.float64) for k in ("rho_d", "f0", "alpha")} | {"error": float(r["error"][0])}
