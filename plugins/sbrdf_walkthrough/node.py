"""``Walkthrough``: a scene's camera path drawn by ``gl`` into PNG/EXR frames and an MP4 beside the arrays."""

from __future__ import annotations

import os
import shutil
import tempfile

import numpy as np

from sbrdf_core.artifacts import ArraySpec, ArtifactKind
from sbrdf_core.nodes.base import BuildContext, NodeKind, Output, Port
from sbrdf_core.params import Param

WALKTHROUGH = ArtifactKind(
    "WalkthroughFrames",
    1,
    "A camera path rendered: frame_0000.png ... (and .exr), walkthrough.mp4 beside the arrays (attrs: scene, frames, "
    "fps, sampling per frame, exposure, device, files).",
    (ArraySpec("wall_ms", "F", "float64", "per frame: milliseconds to glFinish, every pass", timing=True),
     ArraySpec("gpu_ms", "F", "float64", "per frame: the GL time-elapsed query of the main pass", timing=True)),
)


class Walkthrough(NodeKind):
    name = "Walkthrough"
    doc = ("Render a scene's camera_path with the gl renderer: deterministic filtered sampling while moving, "
           "progressive QMC where the path holds still; PNG (and EXR) frames and an MP4, per-frame times.")
    inputs = (Port("material", ("ParamMaps", "TextureSet"), "the material of the scene's artifact: input materials",
                   optional=True),
              Port("lightmaps", ("LightMaps",), "the scene's baked light maps (orders the walkthrough after the "
                   "bake)", optional=True))
    output = WALKTHROUGH
    params = (
        Param("scene", "str", doc="scene file with a camera_path:, relative to the graph file", extra={"path": True}),
        Param("formats", "list", ["png"], "image files per frame: png, exr", item="str"),
        Param("video", "bool", True, "encode walkthrough.mp4 (imageio-ffmpeg, the video extra)"),
        Param("progressive_samples", "int", 8, "Monte Carlo samples per strategy and still frame (environment)",
              bounds=(1, 4096)),
        Param("exposure", "float", None, "display exposure of the PNGs; default: the scene's, else the first "
              "frame's automatic one", nullable=True, bounds=(0.0, None)),
    )

    @classmethod
    def fingerprint(cls, ctx: BuildContext) -> str:
        """The scene's fingerprint (its text, meshes, environment map, light maps): a changed scene re-renders."""
        from sbrdf_lib.scene import scene_fingerprint

        return scene_fingerprint(ctx.params["scene"], ctx.registry)

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask
        import dask.array as da

        from sbrdf_core.nodes.render import material_from
        from sbrdf_lib.camera_path import frames
        from sbrdf_lib.scene import load_scene

        p = ctx.params
        bad = sorted(set(p["formats"]) - {"png", "exr"})
        if bad:
            raise ValueError(f"Walkthrough: formats {bad} are not png or exr")
        art = ctx.inputs.get("material")
        material = material_from(ctx, art) if art is not None else None
        scene = load_scene(p["scene"], registry=ctx.registry)
        if scene.camera_path is None:
            raise ValueError(f"Walkthrough: {p['scene']} has no camera_path:")
        n = len(frames(scene))
        registry = ctx.plugins()
        renderer = registry.create("renderer", "gl", {"scene": p["scene"], "exposure": p["exposure"]})
        renderer.bind(registry)
        out: dict = {}
        work = tempfile.mkdtemp(prefix="sbrdf-walkthrough-")  # frames land beside the arrays in finalize

        def run(kind):
            if not out:
                out.update(renderer.render_path(material, work, formats=tuple(p["formats"]),
                                                video=p["video"], progressive_samples=p["progressive_samples"]))
            return np.asarray(out[kind], np.float64)

        arrays = {k: da.from_delayed(dask.delayed(run, pure=False)(k, dask_key_name=ctx.key(k)), (n,), np.float64)
                  for k in ("wall_ms", "gpu_ms")}

        def finalize(art):
            for name in out.get("files", []):
                shutil.move(os.path.join(work, name), os.path.join(art.url, name))
            shutil.rmtree(work, ignore_errors=True)
            return {k: v for k, v in out.items() if k not in ("wall_ms", "gpu_ms")}

        return Output(arrays=arrays, attrs={"scene": p["scene"], "frames": n}, finalize=finalize, sequential=True)
