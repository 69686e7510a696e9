"""The ``cubemaps`` scene effect: per-object incident-light cube maps (Mühlbacher §4.4.1) for ``cube_map:`` objects.

``gl``: once, when the scene is prepared, the scene *without* the object is
drawn diffuse-only (the light maps' ρ_d·E when the scene has them, else ρ_d ×
the lights plus the environment's ρ_d·D(N); the environment itself where
nothing is seen) from the object's bounding-box centre (or its ``centre:``)
into the six faces of a real GL cube texture with a MIP chain, filtered
seamlessly across faces (``GL_TEXTURE_CUBE_MAP_SEAMLESS``).  The object's
specular lobes are sampled with the deterministic patterns and estimator of
:mod:`.sampling`; each sample's look-up direction is either the sample
direction itself (the environment-at-infinity assumption) or, with
``parallax: true`` and ``planes:``, the direction from the cube map's centre
to the nearest bounding plane the sample ray (P, ω_i) hits (Fig 4.5).  The
MIP level follows Eqs 4.14–4.17 for the face size.

``cpu`` (the reference): Monte Carlo over the same lobes with real ray
casting into the rest of the scene, diffuse-only by the same definition
(shared with :mod:`.mirror`), or the environment where the ray leaves.

Both add the specular part (f_r − ρ_d); the object's diffuse is the
renderer's (lights or light maps) and, without light maps, the environment
effect's ρ_d·D(N).  Each cube-mapped object needs a material of its own.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from sbrdf_core.errors import SbrdfError

from . import CUBE_MAP_PARAMS, sampling
from .mirror import MirrorEffect, Reflector, exclusive_materials

logger = logging.getLogger(__name__)

__all__ = ["CubeMapEffect", "cube_mapped"]

#: GL cube faces in order +X, −X, +Y, −Y, +Z, −Z: (forward, up) of the camera that renders each.
FACES = (((1, 0, 0), (0, -1, 0)), ((-1, 0, 0), (0, -1, 0)), ((0, 1, 0), (0, 0, 1)), ((0, -1, 0), (0, 0, -1)),
         ((0, 0, 1), (0, -1, 0)), ((0, 0, -1), (0, -1, 0)))


def cube_mapped(scene) -> list[int]:
    """Indices of the scene's objects with ``cube_map:``."""
    return [k for k, o in enumerate(scene.objects) if o.params.get("cube_map")]


@dataclasses.dataclass
class CubeTarget(Reflector):
    """A cube-mapped object: its centre, unit planes ``(P, 4)`` (n, d with n·x = d) and options."""

    centre: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    planes: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4)))
    size: int = 64
    parallax: bool = True


class CubeMapEffect(MirrorEffect):
    """Per-object cube maps; the cpu reference and the diffuse-only radiance are the mirror effect's."""

    name = "cubemaps"

    params = CUBE_MAP_PARAMS

    def __init__(self, *, samples: int = 7, estimator: str = "4.25", xi_border: float = sampling.XI_BORDER,
                 ring_radius: float = sampling.RING_RADIUS, line_threshold: float = 4.0, mc_samples: int = 64,
                 seed: int = 0):
        super().__init__(samples=samples, estimator=estimator, xi_border=xi_border, ring_radius=ring_radius,
                         line_threshold=line_threshold, mc_samples=mc_samples, seed=seed)

    @staticmethod
    def wanted(scene) -> bool:
        return bool(cube_mapped(scene)) or scene.section("cube_maps") is not None

    @staticmethod
    def options(scene) -> dict:
        return dict(vars(scene.section("cube_maps"))) if scene.section("cube_maps") is not None else {}

    @staticmethod
    def check(scene) -> list[str]:
        idx = cube_mapped(scene)
        if not idx:
            return ["cube_maps: options are given but no object has cube_map:"]
        out = []
        for k in idx:
            o = scene.objects[k]
            cm = o.params["cube_map"]
            if o.shape == "plane" and o.params.get("reflector"):
                out.append(f"object {k}: a reflector: true plane takes no cube_map:")
            size = int(cm.get("size", 64))
            if size & (size - 1):
                out.append(f"object {k}: cube_map size must be a power of two, got {size}")
            for j, p in enumerate(cm.get("planes") or []):
                if not (isinstance(p, list) and len(p) == 4 and all(isinstance(x, (int, float)) for x in p)
                        and np.linalg.norm(np.asarray(p[:3], float)) > 0):
                    out.append(f"object {k}: cube_map planes[{j}] must be [a, b, c, d] with (a, b, c) not zero, "
                               f"got {p!r}")
            if cm.get("parallax", True) and len(cm.get("planes") or []) == 1:
                out.append(f"object {k}: cube_map parallax needs at least two planes (e.g. floor and ceiling)")
        return out + exclusive_materials(
            scene, idx,
            lambda j, k, m: f"objects {j} and {k} with cube_map: share material {m!r}; give each a material of its own",
            lambda m, k: f"the cube-mapped material {m!r} must not be used by other objects (object {k})")

    def prepare(self, scene, materials=None, gl_context=None) -> None:
        from sbrdf_lib.surface import tessellate

        problems = self.check(scene)
        if problems:
            raise SbrdfError(f"{scene.file}: {problems[0]}")
        self._prepare_common(scene, materials, gl_context)
        self.reflectors = []
        for k in cube_mapped(scene):
            obj = scene.objects[k]
            cm = obj.params["cube_map"]
            if cm.get("centre") is not None:
                centre = np.asarray(cm["centre"], np.float64)
            else:
                pos = tessellate(obj).positions
                centre = 0.5 * (pos.min(0) + pos.max(0))
            planes = np.asarray(cm.get("planes") or np.zeros((0, 4)), np.float64).reshape(-1, 4)
            planes = planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)
            others = dataclasses.replace(scene, objects=tuple(o for j, o in enumerate(scene.objects) if j != k))
            self.reflectors.append(CubeTarget(k, obj.material, (centre, np.array([0.0, 0.0, 1.0])), others,
                                              centre=centre, planes=planes, size=int(cm.get("size", 64)),
                                              parallax=bool(cm.get("parallax", True)) and len(planes) >= 2))
        self.by_material = {r.material: r for r in self.reflectors}

    # -- gl ---------------------------------------------------------------------------------------------------------

    def glsl(self, material, exprs):
        from .cubemaps_glsl import fragment_code

        target = self.by_material.get(material.name)
        if target is None:
            return "", []
        return fragment_code(self, target, material, exprs)

    def gl_prepare(self, drawer) -> None:
        from .cubemaps_glsl import CubePass

        for i, t in enumerate(self.reflectors):
            t.gl = CubePass(self, t, i, drawer)

    def gl_frame(self, drawer) -> None:
        drawer.ctx.enable_direct(0x884F)  # GL_TEXTURE_CUBE_MAP_SEAMLESS: filter across faces

    def gl_camera(self, drawer) -> None:
        self.scene = drawer.scene  # the cube maps do not depend on the camera
