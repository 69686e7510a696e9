"""Camera paths of walkthroughs: a scene's ``camera_path:`` keyframes as one camera per frame.

Positions and look-at points are interpolated separately (linear, or
uniform Catmull-Rom through the keys, which is C1 and passes through every
keyframe), the field of view linearly.  A segment whose two keyframes have
the same pose holds the camera still: its frames are marked ``still`` so a
renderer can refine them progressively instead of repeating the moving
camera's deterministic estimate (Mühlbacher §4.4.2).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["PathFrame", "camera_at", "frames"]


@dataclass(frozen=True)
class PathFrame:
    index: int
    time: float
    camera: Any  # sbrdf_lib.scene.Camera
    still: bool  # the same pose as the previous frame
    refine: int  # still frames in a row before this one (0 when the camera moved)


def _segment(times: np.ndarray, t: float) -> int:
    return int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))


def _catmull_rom(p0, p1, p2, p3, s):
    return 0.5 * ((2 * p1) + (-p0 + p2) * s + (2 * p0 - 5 * p1 + 4 * p2 - p3) * s * s
                  + (-p0 + 3 * p1 - 3 * p2 + p3) * s ** 3)


def _interpolate(keys: list, name: str, i: int, s: float, mode: str) -> np.ndarray:
    a, b = keys[i][name], keys[i + 1][name]
    if mode == "linear" or np.allclose(a, b):  # a hold stays exactly still
        return a + (b - a) * s
    p0 = keys[i - 1][name] if i > 0 else 2 * a - b
    p3 = keys[i + 2][name] if i + 2 < len(keys) else 2 * b - a
    return _catmull_rom(p0, a, b, p3, s)


def camera_at(scene, t: float):
    """The scene's camera at time ``t`` of its path (clamped to the path's span)."""
    path = scene.camera_path
    keys = path.keyframes
    times = np.array([k["time"] for k in keys])
    t = float(np.clip(t, times[0], times[-1]))
    i = _segment(times, t)
    s = (t - times[i]) / (times[i + 1] - times[i])
    pos = _interpolate(keys, "position", i, s, path.interpolation)
    look = _interpolate(keys, "look_at", i, s, path.interpolation)
    f0 = keys[i]["fov_deg"] if keys[i]["fov_deg"] is not None else scene.camera.fov_deg
    f1 = keys[i + 1]["fov_deg"] if keys[i + 1]["fov_deg"] is not None else scene.camera.fov_deg
    return dataclasses.replace(scene.camera, position=pos, look_at=look, fov_deg=float(f0 + (f1 - f0) * s))


def frames(scene, fps: float | None = None) -> list[PathFrame]:
    """One camera per frame at ``k / fps`` from the first keyframe's time to the last's (inclusive)."""
    path = scene.camera_path
    fps = fps if fps is not None else path.fps
    t0, t1 = path.keyframes[0]["time"], path.keyframes[-1]["time"]
    n = int(np.floor((t1 - t0) * fps + 1e-9)) + 1
    out: list[PathFrame] = []
    for k in range(n):
        t = t0 + k / fps
        cam = camera_at(scene, t)
        prev = out[-1].camera if out else None
        still = prev is not None and np.allclose(cam.position, prev.position, atol=1e-9) and \
            np.allclose(cam.look_at, prev.look_at, atol=1e-9) and cam.fov_deg == prev.fov_deg
        out.append(PathFrame(k, t, cam, still, out[-1].refine + 1 if still else 0))
    return out
