"""Walkthroughs: a scene's camera path rendered by ``gl`` as an image sequence and a video (Mühlbacher §4.6.4).

Every frame of :func:`sbrdf_lib.camera_path.frames` is drawn by one
:class:`~sbrdf_render.gl.GLScene` whose camera follows the path
(:meth:`~sbrdf_render.gl.GLScene.set_camera`).  While the camera moves the
scene is drawn as it says (the environment's deterministic filtered
``sampling``, the mirrors' patterns: §4.4.3).  Where the path holds still and
the scene has an environment map, a second GLScene with the environment's
``progressive`` method takes over: ``progressive_samples`` quasi-random
samples per frame and strategy, unfiltered, blended into the running mean of
the still frames so far (§4.4.2); it starts again whenever the camera
moves.  Planar mirrors keep their deterministic patterns (they have no
progressive mode).

Per frame the GL time-elapsed query (main pass) and the wall-clock time to
``glFinish`` (every pass: mirrors, MIP chains; the figure to trust on
llvmpipe) are recorded.  Frames are written as PNG (one exposure for the
whole sequence: the scene's, else the first frame's automatic one) and,
if asked, EXR; the MP4 is encoded from the PNG frames by imageio-ffmpeg
(``pip install 'sbrdf[video]'``).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from types import SimpleNamespace

import numpy as np

from sbrdf_core.errors import SbrdfError

logger = logging.getLogger(__name__)

__all__ = ["encode_video", "progressive_scene", "render_path"]


def progressive_scene(scene, samples: int):
    """The scene with its environment's method switched to ``progressive`` (for the still frames), or None."""
    env = scene.section("environment")
    if env is None:
        return None
    options = dict(getattr(env, "options", None) or {}, method="progressive", mc_samples=samples)
    sections = dict(scene.sections, environment=SimpleNamespace(**dict(vars(env), options=options)))
    return dataclasses.replace(scene, sections=sections)


def render_path(scene, materials: dict, out_dir: str, registry=None, formats: tuple[str, ...] = ("png",),
                video: bool = True, progressive_samples: int = 8, exposure: float | None = None,
                frames: list | None = None) -> dict:
    """Render the scene's camera path into ``out_dir`` (``frame_0000.png`` …, ``walkthrough.mp4``); statistics.

    ``frames``: :class:`~sbrdf_lib.camera_path.PathFrame` list (default: the scene's path at its fps).
    """
    from sbrdf_core.io import write_exr, write_png
    from sbrdf_core.nodes.render import display_exposure, to_display
    from sbrdf_lib.camera_path import frames as path_frames

    from .gl import GLScene, device_name

    if scene.camera_path is None and frames is None:
        raise SbrdfError(f"{scene.file}: the scene has no camera_path: to walk through")
    frames = frames if frames is not None else path_frames(scene)
    os.makedirs(out_dir, exist_ok=True)
    first = dataclasses.replace(scene, camera=dataclasses.replace(frames[0].camera, resolution=scene.camera.resolution))
    moving = GLScene(first, materials, registry=registry)
    still_scene = progressive_scene(first, progressive_samples)
    still = None
    gpu_ms, wall_ms, kinds, files = [], [], [], []
    exposure = exposure if exposure is not None else scene.exposure
    try:
        for f in frames:
            use_still = f.still and still_scene is not None
            if use_still and still is None:
                still = GLScene(still_scene, materials, registry=registry)
            drawer = still if use_still and still is not None else moving
            if not f.still or drawer is still and f.refine == 1:  # a new pose, or the first still frame
                drawer.set_camera(f.camera)
            t0 = time.perf_counter()
            frame = drawer.draw(read=True)
            wall_ms.append((time.perf_counter() - t0) * 1e3)
            gpu_ms.append(frame.gpu_ms)
            kinds.append("progressive" if use_still else "deterministic")
            image = frame.image
            assert image is not None, "drawn with read=True"
            if exposure is None:
                exposure = display_exposure(image)
            name = f"frame_{f.index:04d}"
            write_png(os.path.join(out_dir, name + ".png"), to_display(image, exposure, scene.gamma))
            files.append(name + ".png")
            if "exr" in formats:
                write_exr(os.path.join(out_dir, name + ".exr"), image.astype(np.float32))
                files.append(name + ".exr")
    finally:
        moving.release()
        if still is not None:
            still.release()
    fps = scene.camera_path.fps if scene.camera_path is not None else 24.0
    if video:
        encode_video([os.path.join(out_dir, f"frame_{f.index:04d}.png") for f in frames],
                     os.path.join(out_dir, "walkthrough.mp4"), fps)
        files.append("walkthrough.mp4")
    stats = {"frames": len(frames), "fps": fps, "gpu_ms": gpu_ms, "wall_ms": wall_ms, "sampling": kinds,
             "gpu_ms_median": float(np.median(gpu_ms)), "wall_ms_median": float(np.median(wall_ms)),
             "exposure": float(exposure), "device": device_name(), "files": files}
    logger.info("walkthrough of %s: %d frames, median %.1f ms wall", scene.file, len(frames), stats["wall_ms_median"])
    return stats


def encode_video(pngs: list[str], path: str, fps: float) -> None:
    """An H.264 MP4 of PNG frames (imageio-ffmpeg; even sizes: odd ones are padded by a pixel)."""
    from sbrdf_core.extras import require
    from sbrdf_core.io import read_png

    ffmpeg = require("imageio_ffmpeg", "video", "walkthrough videos")
    first = read_png(pngs[0])
    H, W = first.shape[:2]
    H2, W2 = H + H % 2, W + W % 2
    writer = ffmpeg.write_frames(path, (W2, H2), fps=fps, codec="libx264", pix_fmt_out="yuv420p", quality=8,
                                 macro_block_size=1, output_params=["-loglevel", "error"])
    writer.send(None)
    try:
        for p in pngs:
            img = read_png(p)[..., :3]
            if img.dtype != np.uint8:
                img = (img / 257).astype(np.uint8)
            frame = np.zeros((H2, W2, 3), np.uint8)
            frame[:H, :W] = img
            writer.send(np.ascontiguousarray(frame))
    finally:
        writer.close()
