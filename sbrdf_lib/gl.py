"""OpenGL through moderngl on EGL: the context, parameter textures in GLSL, and the end of a frame.

What the ``gl`` renderer and the scene effects that draw with it (the
environment and mirror effects, third-party effects) share: one standalone
EGL context per process (:func:`context`), the GLSL expressions of a model's
parameters packed into RGBA textures (:func:`parameter_exprs`), clip planes
from the scene's meshes, and :class:`Drawer`, the resource bookkeeping and
read-back of a frame.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from sbrdf_core.errors import SbrdfError

if TYPE_CHECKING:
    from .scene import Scene

__all__ = ["Drawer", "Frame", "check_size", "clip_planes", "context", "device_name", "parameter_exprs"]

logger = logging.getLogger(__name__)

_CONTEXT = None


def context():
    """The process's standalone EGL context (created once; EGL contexts are expensive)."""
    global _CONTEXT
    if _CONTEXT is None:
        from sbrdf_core.extras import require

        moderngl = require("moderngl", feature="OpenGL rendering (gl, geforce4, shading maps, environment maps)")
        try:
            _CONTEXT = moderngl.create_context(standalone=True, backend="egl", require=330)
        except Exception as e:  # no libEGL, no driver
            raise SbrdfError(f"gl renderer: cannot create an OpenGL 3.3 context through EGL ({e}); install "
                             "Mesa's EGL (Debian: libegl1 libgl1-mesa-dri) or use the cpu renderer") from None
        logger.info("EGL context: %s", _CONTEXT.info.get("GL_RENDERER"))
    return _CONTEXT


def device_name() -> str:
    ctx = context()
    return f"{ctx.info['GL_RENDERER']} ({ctx.info['GL_VENDOR']})"


def parameter_exprs(model, samplers: str = "u_params") -> tuple[int, dict[str, str]]:
    """Number of RGBA textures holding the packed parameters, and each parameter's GLSL expression."""
    exprs, offset = {}, 0
    for p in model.parameters:
        comps = [f"{samplers}_{(offset + c) // 4}.{'xyzw'[(offset + c) % 4]}" for c in range(p.channels)]
        exprs[p.name] = comps[0] if p.channels == 1 else f"vec{p.channels}({', '.join(comps)})"
        offset += p.channels
    return (offset + 3) // 4, exprs


def clip_planes(camera, meshes: dict) -> tuple[float, float]:
    """Near and far planes from the vertices' depths along the view (meshes of any size), with a margin."""
    forward = camera.basis()[2]
    depth = np.concatenate([(m.positions - camera.position) @ forward for m in meshes.values()])
    far = float(depth.max(initial=1.0)) * 1.01 + 1e-6
    return max(far * 1e-5, float(depth.min(initial=0.0)) * 0.99), far


def check_size(ctx, scene) -> None:
    """An error, rather than a driver failure, when the (supersampled) framebuffer exceeds what the driver allows."""
    W, H = scene.camera.resolution
    limit = int(ctx.info.get("GL_MAX_TEXTURE_SIZE", 16384) or 16384)
    if max(W, H) > limit:
        raise SbrdfError(f"{scene.file}: gl renderer: the framebuffer would be {W}×{H} (the camera's resolution "
                         f"× √antialias) but this driver allows {limit} pixels per side; lower antialias: or the "
                         "resolution, or use the cpu renderer")


@dataclass
class Frame:
    image: np.ndarray | None  # (H, W, 3) float32 linear, row 0 at the top; None for a frame not read back
    gpu_ms: float  # GL time-elapsed query around the draw calls
    wall_ms: float  # including glFinish
    stats: dict = field(default_factory=dict)


class Drawer:
    """What GL drawers share: resources released together, and the end of a frame (timing and read-back).

    Subclasses set ``ctx``, ``scene``, ``query`` and ``_res`` (a list) before drawing.
    """

    ctx: Any  # a moderngl.Context (moderngl ships no type information)
    scene: Scene
    query: Any  # the moderngl.Query timing the draw calls
    _res: list

    def _keep(self, obj):
        self._res.append(obj)
        return obj

    def _finish(self, target, t0: float, read: bool) -> tuple[np.ndarray | None, float, float]:
        """Wait for the frame; its image from ``target`` (row 0 at the top) if ``read``, GPU and wall ms."""
        self.ctx.finish()
        wall = (time.perf_counter() - t0) * 1e3
        elapsed = self.query.elapsed
        gpu = elapsed / 1e6 if 0 < elapsed < 2**32 - 1 else wall  # llvmpipe may answer UINT_MAX on a first frame
        image = None
        if read:
            W, H = self.scene.camera.resolution
            raw = np.frombuffer(target.read(components=3, dtype="f4"), dtype=np.float32).reshape(H, W, 3)
            image = raw[::-1].copy()  # GL's row 0 is the bottom
        return image, gpu, wall

    def release(self) -> None:
        for obj in reversed(self._res):
            if hasattr(obj, "release"):  # moderngl's Query has no release()
                obj.release()
        self._res = []
