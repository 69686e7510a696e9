"""``DarkFrame`` and ``FlatField``: the calibration captures, as nodes.

A camera adds a dark signal to every photograph (a black-level pedestal and
dark current growing with the exposure) and sees the scene through a lens
that vignettes and sensels that differ in sensitivity.  Two calibration
captures measure both with the capture's camera, and the Capture node's
``dark`` and ``flat`` inputs take them out of every exposure before the
bracket is merged (:mod:`sbrdf_lib.calibration`, equation (1)):

    corrected = (raw_linear - offset - rate · t) / flat

=================  =========  =========================================================
node / parameter   type       meaning (default)
=================  =========  =========================================================
**DarkFrame**                 lens capped, light off: ``frames`` frames at each time
``camera``         dict       ``{device, params}``: the capture's camera (required)
``times_s``        list       exposure times, s; two or more distinct ones separate the
                              pedestal from dark current (required)
``frames``         int        frames averaged per time (8)
``max_level``      float      refuse the capture when a dark frame's mean signal is
                              above this fraction of full scale: the lens is not
                              capped (0.25)
**FlatField**                 a uniform target filling the view: ``frames`` frames
``camera``         dict       ``{device, params}``: the capture's camera (required)
``time_s``         float      exposure time, s: the target near half scale (required)
``frames``         int        frames averaged (8)
``centre_fraction`` float     central window (share of height and width) the flat is
                              normalised to 1 over (0.1)
``max_saturated``  float      refuse a flat with more than this share of its pixels
                              saturated (0.001)
=================  =========  =========================================================

``FlatField`` has an optional ``dark`` input: give it, or the pedestal stays
in the flat and bends its shape.  The arrays are ``(H, W, 3)`` in linear
signal units: integer codes through the camera's response (a virtual
camera's recorded curve; a frame camera must deliver linear codes) or
normalised by the dtype's maximum; so the photographs and the calibration
go through the same linearisation in the ``folder`` reader.

How the frames are taken: a camera device with ``dark_frame`` and
``flat_frame`` (the ``virtual-camera``) simulates the capped lens and the
uniform target.  Any frame camera (``pylon``, ``uvc``, ``gphoto``) is set to
each time and triggered ``frames`` times; covering the lens, or putting the
diffuser or target in front of it, is the operator's step, so on a rig run
the calibration nodes alone first (``sbrdf run graph.yaml --only dark``, cap
off, ``--only flat``) and the capture after: the cached artifacts are reused.
An emulated Basler camera's ``emulation_frames`` pattern gets the frame
index as ``{pose}`` and the time's index as ``{exposure}``.

Example (``graphs`` YAML; the same ``camera`` mapping as the capture's)::

    dark:    {kind: DarkFrame, params: {camera: *cam, times_s: [0.25, 1.0], frames: 8}}
    flat:    {kind: FlatField, in: {dark: dark}, params: {camera: *cam, time_s: 0.5}}
    capture: {kind: Capture, plugin: gonio, in: {dark: dark, flat: flat}, params: {...}}
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from sbrdf_core.artifacts import ArraySpec, ArtifactKind
from sbrdf_core.contracts import optional
from sbrdf_core.errors import ParameterError, SbrdfError
from sbrdf_core.nodes.base import BuildContext, NodeKind, Output, Port
from sbrdf_core.params import REQUIRED, Param, plugin_reference

log = logging.getLogger(__name__)

DARK_FRAME = ArtifactKind(
    "DarkFrame",
    1,
    "A camera's dark signal per sensel, D(t) = offset + rate * t, from lens-capped frames (attrs: camera, times_s, "
    "frames, model offset or offset+rate, mean offset and rate).",
    (ArraySpec("offset", "HWC", "float32", "pedestal (black level) per sensel and channel, linear signal"),
     ArraySpec("rate", "HWC", "float32", "dark current per sensel and channel, linear signal per second"),
     ArraySpec("times_s", "T", "float64", "exposure times the dark frames were taken at, s")),
)

FLAT_FIELD = ArtifactKind(
    "FlatField",
    1,
    "A camera's relative sensitivity per sensel (vignetting, pixel response), 1 at the image centre, from a "
    "uniform target (attrs: camera, time_s, frames, centre_fraction, min, corner mean, dark_corrected).",
    (ArraySpec("flat", "HWC", "float32", "normalised flat field per sensel and channel (1 at the centre)"),),
)

CAMERA = Param("camera", "dict", REQUIRED, "camera device {device, params}: the capture's camera",
               schema=plugin_reference("device", "camera"))
FRAMES = Param("frames", "int", 8, "frames averaged (their noise is added to every corrected photograph / sqrt(frames))",
               bounds=(1, 10000))


def _open(registry, config: dict):
    if not isinstance(config, dict) or "device" not in config:
        raise ParameterError(f"camera: expected {{device: <device plugin>, params: {{...}}}}, got {config!r}")
    cam = registry.create("device", str(config["device"]), dict(config.get("params") or {}))
    if optional(cam, "bind", "device") is not None:
        cam.bind(registry)
    return cam


def _response(cam):
    """The camera's response curve (``None``: linear codes) for :func:`sbrdf_lib.calibration.linear_signal`."""
    if hasattr(cam, "camera_info"):
        given = cam.camera_info().get("response")
        if isinstance(given, dict):
            from sbrdf_lib.response import ResponseCurve

            return ResponseCurve.from_manifest(given)
        return None
    if not getattr(cam, "linear", True):
        raise SbrdfError(f"camera {getattr(cam, 'name', '?')!r} does not deliver linear codes; calibration frames "
                         "need them (switch the camera to a raw/linear pixel format)")
    return None


def _record(cam, config: dict) -> dict:
    if hasattr(cam, "info"):
        return dict(cam.info())
    return {"driver": str(config["device"]), "width": int(cam.width), "height": int(cam.height)}


def take_frames(registry, config: dict, what: str, times_s: list[float], frames: int) -> dict[str, Any]:
    """Open the camera, take ``frames`` frames at each time (``what``: dark or flat), close it.

    Returns ``{"signal": [(H, W, 3) mean linear signal per time], "saturated": [share per time], "times_s":
    [the times the camera used], "camera": its record}``.
    """
    from sbrdf_lib.calibration import linear_signal
    from sbrdf_lib.camera import saturated_fraction

    cam = _open(registry, config)
    try:
        response = _response(cam)
        simulated = hasattr(cam, f"{what}_frame")
        if not simulated and not hasattr(cam, "grab"):
            raise SbrdfError(f"camera {config['device']!r} can neither grab frames nor simulate {what} frames")
        means, saturated, used = [], [], []
        for k, t in enumerate(times_s):
            t_used = float(t) if simulated else float(cam.set_exposure(float(t)))
            total, sat = np.zeros((), np.float64), 0.0
            for i in range(frames):
                raw = getattr(cam, f"{what}_frame")(t_used, frame_id=i) if simulated else cam.grab(pose_id=i, exposure_index=k)
                if np.asarray(raw).dtype.kind == "u":
                    sat = max(sat, saturated_fraction(raw))
                s = linear_signal(raw, response).astype(np.float64)
                total = total + s
            means.append((total / frames).astype(np.float32))
            saturated.append(sat)
            used.append(t_used)
        return {"signal": means, "saturated": saturated, "times_s": used, "camera": _record(cam, config)}
    finally:
        close = getattr(cam, "close", None)
        if callable(close):
            close()


def _delayed_frames(ctx: BuildContext, what: str, times: list[float]):
    import dask

    registry = ctx.plugins()
    params = ctx.params
    return dask.delayed(take_frames)(registry, params["camera"], what, times, int(params["frames"]),
                                          dask_key_name=ctx.key(f"{what}-frames"))


class DarkFrame(NodeKind):
    name = "DarkFrame"
    doc = ("Lens-capped frames of the capture's camera at one or more exposure times: the dark signal per sensel, "
           "offset (black level) + rate (dark current) * t, for the Capture node's dark input.")
    output = DARK_FRAME
    params = (
        CAMERA,
        Param("times_s", "list", REQUIRED, "exposure times, s; two or more distinct ones separate the pedestal from "
              "dark current (one time: its dark signal is used at every exposure)", item="float", unit="s"),
        FRAMES,
        Param("max_level", "float", 0.25, "refuse dark frames whose mean signal is above this share of full scale (the "
              "lens is not capped)", bounds=(0.0, 1.0)),
    )

    @classmethod
    def prepare(cls, ctx: BuildContext) -> dict[str, Any]:
        times = [float(t) for t in ctx.params["times_s"]]
        if not times or not all(t > 0 for t in times):
            raise ParameterError(f"node {ctx.node!r}: times_s: expected one or more positive exposure times, got "
                                 f"{ctx.params['times_s']!r}")
        return {"frames": _delayed_frames(ctx, "dark", times)}

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        from sbrdf_lib.calibration import fit_dark

        prepared = ctx.prepared or {}
        got = prepared["frames"]
        level = [float(s.mean()) for s in got["signal"]]
        if max(level) > ctx.params["max_level"]:
            k = int(np.argmax(level))
            raise SbrdfError(f"node {ctx.node!r}: the dark frame at {got['times_s'][k]:g} s has mean signal "
                             f"{level[k]:.3g} of full scale, above max_level {ctx.params['max_level']:g}: cap the lens "
                             "and switch the light off, then run the node again")
        offset, rate = fit_dark(got["times_s"], got["signal"])
        distinct = len(set(got["times_s"])) > 1
        attrs = {"camera": got["camera"], "times_s": got["times_s"], "frames": int(ctx.params["frames"]),
                 "model": "offset+rate" if distinct else "offset",
                 "mean_offset": offset.reshape(-1, 3).mean(axis=0).tolist(),
                 "mean_rate": rate.reshape(-1, 3).mean(axis=0).tolist()}
        log.info("%s: dark offset %s, rate %s /s", ctx.node, attrs["mean_offset"], attrs["mean_rate"])
        return Output(arrays={"offset": da.from_array(offset), "rate": da.from_array(rate),
                              "times_s": da.from_array(np.asarray(got["times_s"], np.float64))}, attrs=attrs)


class FlatField(NodeKind):
    name = "FlatField"
    doc = ("Frames of a uniform target with the capture's camera, dark-corrected and normalised to 1 at the image "
           "centre: vignetting and pixel response, for the Capture node's flat input.")
    output = FLAT_FIELD
    inputs = (Port("dark", (DARK_FRAME,), "the camera's dark model, subtracted before normalising", optional=True),)
    params = (
        CAMERA,
        Param("time_s", "float", REQUIRED, "exposure time, s: the target near half of full scale", bounds=(1e-9, None),
              unit="s"),
        FRAMES,
        Param("centre_fraction", "float", 0.1, "central window (share of height and width) normalised to 1",
              bounds=(1e-6, 1.0)),
        Param("max_saturated", "float", 0.001, "refuse a flat with more than this share of its pixels saturated",
              bounds=(0.0, 1.0)),
    )

    @classmethod
    def prepare(cls, ctx: BuildContext) -> dict[str, Any]:
        wanted = {"frames": _delayed_frames(ctx, "flat", [float(ctx.params["time_s"])])}
        if "dark" in ctx.inputs:
            wanted.update(offset=ctx.inputs["dark"].array("offset"), rate=ctx.inputs["dark"].array("rate"))
        return wanted

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        from sbrdf_lib.calibration import correct, normalise_flat

        prepared = ctx.prepared or {}
        got = prepared["frames"]
        (signal,), (saturated,), (t,) = got["signal"], got["saturated"], got["times_s"]
        if saturated > ctx.params["max_saturated"]:
            raise SbrdfError(f"node {ctx.node!r}: {saturated:.2%} of the flat field's pixels are saturated at {t:g} s "
                             f"(max_saturated {ctx.params['max_saturated']:g}); shorten time_s or dim the target")
        dark = "offset" in prepared
        if dark:
            if prepared["offset"].shape != signal.shape:
                raise SbrdfError(f"node {ctx.node!r}: the dark input is {prepared['offset'].shape[1::-1]} pixels, "
                                 f"the flat {signal.shape[1::-1]}; take both with the same camera and region of interest")
            signal = correct(signal, t, prepared["offset"], prepared["rate"])
        try:
            flat = normalise_flat(signal, ctx.params["centre_fraction"])
        except ValueError as e:
            raise SbrdfError(f"node {ctx.node!r}: {e}") from None
        H, W = flat.shape[:2]
        c = max(1, min(H, W) // 10)
        corners = np.concatenate([flat[:c, :c], flat[:c, -c:], flat[-c:, :c], flat[-c:, -c:]]).reshape(-1, 3)
        attrs = {"camera": got["camera"], "time_s": t, "frames": int(ctx.params["frames"]),
                 "centre_fraction": float(ctx.params["centre_fraction"]), "dark_corrected": dark,
                 "min": flat.reshape(-1, 3).min(axis=0).tolist(), "corner_mean": corners.mean(axis=0).tolist()}
        if not dark:
            log.warning("%s: a flat field without a dark input keeps the camera's pedestal in its shape; wire "
                        "in: {dark: <DarkFrame node>}", ctx.node)
        return Output(arrays={"flat": da.from_array(flat)}, attrs=attrs)
