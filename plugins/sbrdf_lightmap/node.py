"""``LightmapBake``: bake a scene's light maps (:mod:`.bake`) into the folder its ``lightmap:`` names."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from sbrdf_core.artifacts import ArraySpec, ArtifactKind
from sbrdf_core.errors import SbrdfError
from sbrdf_core.nodes.base import BuildContext, NodeKind, Output, Port
from sbrdf_core.params import Param

if TYPE_CHECKING:
    from sbrdf_lib.scene import Scene

LIGHT_MAPS = ArtifactKind(
    "LightMaps",
    1,
    "Per-object irradiance maps of a scene (attrs: scene, directory, files, size, bounces, samples, bake_s); the EXR "
    "files are written into the scene's lightmap: directory, where the renderers read them.",
    (ArraySpec("irradiance", "OVUC", "float32", "E per object and texel of its UV chart (object, v, u, RGB)"),),
)


def load(registry, scene_path: str, material=None):
    """The scene and its resolved materials, through the ``cpu`` renderer (plugins reach plugins by registry)."""
    renderer = registry.create("renderer", "cpu", {"scene": scene_path})
    renderer.bind(registry)
    return renderer.load(material)


def environment(registry, scene, materials):
    """The scene's environment as ``radiance(dirs)`` (the environment scene effect), or None."""
    if scene.section("environment") is None:
        return None
    cls = registry.load(registry.get("scene-effect", "environment"))
    env = registry.create("scene-effect", "environment", cls.options(scene))
    env.prepare(scene, materials, None)
    return env


def bake_scene(registry, scene_path: str, material=None) -> tuple[dict, dict, Scene]:
    """Bake and write the maps of the scene file; returns the maps, statistics and the scene."""
    from sbrdf_core.io import write_exr
    from sbrdf_lib.lightmap import map_path

    from .bake import bake

    scene, materials = load(registry, scene_path, material)
    if scene.lightmap is None:
        raise SbrdfError(f"{scene_path}: the scene has no lightmap: section (directory: where the maps go)")
    maps, stats = bake(scene, materials, environment(registry, scene, materials))
    os.makedirs(scene.lightmap.directory, exist_ok=True)
    stats["maps"] = []  # in the scene's folder, not beside the arrays (the renderers read them there)
    for k, E in maps.items():
        write_exr(map_path(scene.lightmap.directory, k), E)
        stats["maps"].append(map_path(scene.lightmap.directory, k))
    return maps, stats, scene


class LightmapBake(NodeKind):
    name = "LightmapBake"
    doc = ("Bake per-object irradiance light maps of a scene (point, directional, area lights, environment; direct "
           "plus the scene's lightmap: bounces) into its lightmap: directory, for the renderers' k_d/pi E (Eq 4.1).")
    inputs = (Port("material", ("ParamMaps", "TextureSet"), "the material of the scene's artifact: input materials",
                   optional=True),)
    output = LIGHT_MAPS
    params = (Param("scene", "str", doc="scene file with a lightmap: section, relative to the graph file",
                    extra={"path": True}),)

    @classmethod
    def fingerprint(cls, ctx: BuildContext) -> str:
        """The scene file's text: an edited scene re-bakes (its own maps are not part of it, or every bake would)."""
        import hashlib

        try:
            from sbrdf_core.input_files import read_bytes

            return hashlib.sha256(read_bytes(ctx.params["scene"], text=True)).hexdigest()  # never a device whole
        except OSError:
            return ""

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask
        import dask.array as da

        from sbrdf_core.nodes.render import material_from

        art = ctx.inputs.get("material")
        material = material_from(ctx, art) if art is not None else None
        out: dict = {}

        def run():
            maps, stats, scene = bake_scene(ctx.registry, ctx.params["scene"], material)
            out.update(stats, directory=scene.lightmap.directory)
            return np.stack([maps[k] for k in sorted(maps)]).astype(np.float32)

        from sbrdf_lib.scene import load_scene

        scene = load_scene(ctx.params["scene"], registry=ctx.registry)
        if scene.lightmap is None:
            raise SbrdfError(f"{ctx.params['scene']}: LightmapBake needs a lightmap: section in the scene")
        S, N = scene.lightmap.size, len(scene.objects)
        arr = da.from_delayed(dask.delayed(run, pure=True)(dask_key_name=ctx.key("bake")), (N, S, S, 3), np.float32)

        def finalize(_art):
            return {k: v for k, v in out.items()}

        return Output(arrays={"irradiance": arr}, attrs={"scene": ctx.params["scene"], "size": S, "objects": N,
                                                        "bounces": scene.lightmap.bounces,
                                                        "samples": scene.lightmap.samples},
                      finalize=finalize, sequential=True)
