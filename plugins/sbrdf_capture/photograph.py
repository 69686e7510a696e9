"""Photographing a camera device into a capture folder, and a pose list to photograph.

:func:`capture_to_folder` drives a camera device that photographs a pose
itself (``photograph(light_pos_mm, R, t, exposure_s, ...)``: the
``virtual-camera`` of ``sbrdf_devices``, created through the registry and
handed in) through a list of poses into an ``sbrdf-capture/1`` folder with
:class:`~sbrdf_lib.capture_folder.CaptureFolderWriter`, resumably; the
``virtual-folder`` source (:mod:`.virtual_folder`), tests and benchmarks use
it.  :func:`orbit_poses` is the simple pose list of simulations: camera and
light on two Fibonacci spirals over the hemisphere.  Neither imports a
device.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping, Sequence

import numpy as np

from sbrdf_core.errors import ParameterError


def _exposure_lists(exposures: float | Sequence[float | Sequence[float]], n: int) -> list[list[float]]:
    if isinstance(exposures, (int, float, numbers.Real)):  # Python and NumPy numbers alike
        return [[float(exposures)]] * n
    out = [[float(e)] if isinstance(e, (int, float, numbers.Real)) else [float(x) for x in e] for e in exposures]
    if len(out) != n:
        raise ParameterError(f"capture_to_folder: {len(out)} exposure lists for {n} poses")
    for i, e in enumerate(out):
        if not 1 <= len(e) <= 3:
            raise ParameterError(f"capture_to_folder: pose {i} has {len(e)} exposures; a bracket has 1 to 3")
    return out


def capture_to_folder(camera, folder, light_pos, R, t, exposures, *, pose_ids: Sequence[int] | None = None,
                      light: Mapping | None = None, image_format: str = "png", durable: bool = True,
                      progress=None, stop_after: int | None = None, extra: Mapping | None = None):
    """Photograph every pose with ``camera`` into an ``sbrdf-capture/1`` folder; resumable.

    Parameters
    ----------
    camera
        Any device with ``camera_info()``, ``sample_info()`` and
        ``photograph(light_pos_mm, R, t, exposure_s, pose_id=, exposure_index=)``;
        optional ``light_info()``, ``simulation_info()`` and ``true_poses``.
    folder
        Target folder; an interrupted capture there is resumed (poses already
        recorded are skipped, the rest are taken and written).
    light_pos, R, t
        ``(P, 3)``, ``(P, 3, 3)``, ``(P, 3)``: nominal light position and
        world-to-camera extrinsics per pose, sample frame, mm.
    exposures
        One time for all, or per pose a time or a list of 1–3 times (a bracket).
    pose_ids
        Pose ids to record (default ``0 .. P-1``).
    light
        The manifest's ``light`` section (default ``camera.light_info()``).
    stop_after
        Take at most this many new poses and return without finishing
        (simulates an interruption in tests).
    extra
        Additional top-level manifest keys (e.g. the ``rig`` record of the
        ``virtual-folder`` capture source), beside ``simulation``.

    Returns the final :class:`~sbrdf_lib.capture_folder.Manifest`, or
    ``None`` when stopped early.
    """
    from sbrdf_lib.capture_folder import CaptureFolderWriter

    light_pos = np.asarray(light_pos, np.float64).reshape(-1, 3)
    P = light_pos.shape[0]
    R = np.asarray(R, np.float64).reshape(P, 3, 3)
    t = np.asarray(t, np.float64).reshape(P, 3)
    times = _exposure_lists(exposures, P)
    ids = list(range(P)) if pose_ids is None else [int(i) for i in pose_ids]
    light = dict(light) if light is not None else camera.light_info()
    header_extra = {"simulation": camera.simulation_info()} if hasattr(camera, "simulation_info") else {}
    header_extra.update(extra or {})
    writer = CaptureFolderWriter(folder, camera.sample_info(), camera.camera_info(), light,
                                 image_format=image_format, durable=durable, extra=header_extra or None)
    taken = 0
    for i, pid in enumerate(ids):
        if pid in writer.done_ids:
            continue
        if stop_after is not None and taken >= stop_after:
            return None
        images = [(camera.photograph(light_pos[i], R[i], t[i], ts, pose_id=pid, exposure_index=k), ts)
                  for k, ts in enumerate(times[i])]
        pose_extra = None
        true = getattr(camera, "true_poses", {}).get(pid)
        if true is not None:
            pose_extra = {"simulation": {"true_light_pos_mm": true[0].tolist(), "true_R": true[1].tolist(),
                                         "true_t": true[2].tolist()}}
        writer.write_pose(pid, light_pos[i], R[i], t[i], images, extra=pose_extra)
        taken += 1
        if progress is not None:
            progress(len(writer.done_ids), len(ids))
    return writer.finish()


def orbit_poses(n: int, camera_distance_mm: float = 350.0, light_distance_mm: float = 450.0,
                max_camera_theta_deg: float = 50.0, max_light_theta_deg: float = 65.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A simple pose list for simulations: ``(light_pos (n, 3), R (n, 3, 3), t (n, 3))``.

    Camera and light on two decorrelated Fibonacci spirals over the hemisphere,
    the camera looking at the sample centre (not a planned gonioreflectometer
    path; the rig's pose planner provides those).
    """
    from sbrdf_core.geometry import fibonacci_hemisphere, look_at

    cams = fibonacci_hemisphere(n, max_camera_theta_deg, offset=2.0) * camera_distance_mm
    lights = fibonacci_hemisphere(n, max_light_theta_deg)[::-1] * light_distance_mm
    Rt = [look_at(c) for c in cams]
    return lights, np.stack([R for R, _ in Rt]), np.stack([t for _, t in Rt])
