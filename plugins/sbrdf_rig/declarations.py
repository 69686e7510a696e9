"""The rig's parameters, declared once and read without importing the drivers or the capture source.

``sbrdf plugins``, graph validation and the reference docs read these through
the :class:`~sbrdf_core.plugin.PluginSpec` of each contribution
(``__init__.py``); the implementations (:mod:`.ptu`, :mod:`.indexer`,
:mod:`.gonio`), imported when a graph runs them, take the same tuples as
their ``params``.  This module imports only :mod:`sbrdf_core.params` and
:mod:`sbrdf_lib.serial_params` (no pyserial, no NumPy).
"""

from __future__ import annotations

from sbrdf_core.params import REQUIRED, Param, plugin_reference
from sbrdf_lib.serial_params import LINK_PARAMS

#: Arc-seconds per position of the Directed Perception / FLIR PTU-46 family: a PTU-46-17.5 at full step
#: (185.1428) down to a PTU-46-70 at eighth step; a unit always reports one of these.
PTU46_RESOLUTIONS_ARCSEC = tuple(round(185.1428 / 2 ** k, 4) for k in range(6))

PTU = (
    *LINK_PARAMS,
    Param("pan_limits_deg", "list", [-159.0, 159.0], "pan soft limits [low, high], intersected with the unit's",
          length=2, item="float", bounds=(-360.0, 360.0), unit="deg"),
    Param("tilt_limits_deg", "list", [-47.0, 31.0], "tilt soft limits [low, high], intersected with the unit's",
          length=2, item="float", bounds=(-360.0, 360.0), unit="deg"),
    Param("speed_deg_s", "float", 20.0, "pan and tilt speed", bounds=(0.01, 1000.0), unit="deg/s"),
    Param("resolutions_arcsec", "list", list(PTU46_RESOLUTIONS_ARCSEC),
          "resolutions the controller model can report (PTU-46 family by default); a PR/TR reading must be one of "
          "them and read the same twice; [] checks agreement only", item="float", bounds=(1e-6, None),
          unit="arcsec"),
)

INDEXER = (
    *LINK_PARAMS,
    Param("axis", "int", 1, "controller axis number", bounds=(1, 4)),
    Param("gear_ratio", "float", 90.0, "motor revolutions per output revolution", bounds=(1e-3, None)),
    Param("limits_deg", "list", [10.0, 175.0], "soft limits [low, high] of the output shaft (light arm: 10-175 deg)",
          length=2, item="float", bounds=(-3600.0, 3600.0), unit="deg"),
    Param("speed_deg_s", "float", 20.0, "output-shaft speed", bounds=(0.01, 1000.0), unit="deg/s"),
    Param("acceleration_deg_s2", "float", 40.0, "output-shaft acceleration", bounds=(0.01, 10000.0),
          unit="deg/s^2"),
    Param("poll_s", "float", 0.01, "status polling interval while a move runs", bounds=(0.0, 1.0), unit="s"),
)

# -- declared sub-schemas of the nested parameters (validated with paths like ``motors.arm.device``) -------------

#: One entry of ``motors``.
MOTOR_SCHEMA = (
    Param("device", "str", REQUIRED, "device plugin: ptu, indexer or any device with MotorController's API",
          extra={"plugin_category": "device"}),
    Param("params", "dict", {}, "the device's parameters ({port: /dev/ttyUSB0 | sim, ...})", nullable=True),
    Param("axes", "dict", None, "joint -> driver axis; default ptu {pan: pan_deg, tilt: tilt_deg}, indexer "
          "{light: angle_deg}", nullable=True),
)
#: ``camera``: a device and its parameters.
CAMERA_SCHEMA = plugin_reference("device", "camera")
#: ``geometry``: the fields of :class:`~sbrdf_lib.rig_geometry.RigGeometry` (defaults: the thesis rig).
GEOMETRY_SCHEMA = (
    Param("camera_distance_mm", "float", 1084.0, "camera distance from the pan axis", unit="mm"),
    Param("light_distance_mm", "float", 1000.0, "light arm radius", unit="mm"),
    Param("camera_height_mm", "float", 0.0, "camera height above the tilt axis", unit="mm"),
    Param("light_height_mm", "float", 0.0, "light height above the tilt axis", unit="mm"),
    Param("tilt_axis_offset_mm", "list", [0.0, 0.0, 0.0], "tilt axis offset from the pan axis (pan frame)",
          length=3, item="float", unit="mm"),
    Param("sample_standoff_mm", "float", 25.4, "sample surface in front of the tilt axis", unit="mm"),
    Param("sample_center_offset_mm", "list", [0.0, 0.0], "sample centre offset from the roll axis", length=2,
          item="float", unit="mm"),
    Param("pan_zero_deg", "float", 0.0, "pan encoder zero", unit="deg"),
    Param("tilt_zero_deg", "float", 0.0, "tilt encoder zero", unit="deg"),
    Param("roll_zero_deg", "float", 0.0, "roll encoder zero", unit="deg"),
    Param("light_zero_deg", "float", 0.0, "light arm encoder zero", unit="deg"),
    Param("pan_limits_deg", "list", [-170.0, 170.0], "pan range [low, high]", length=2, item="float", unit="deg"),
    Param("tilt_limits_deg", "list", [-80.0, 80.0], "tilt range [low, high]", length=2, item="float", unit="deg"),
    Param("roll_limits_deg", "list", [-180.0, 180.0], "roll range [low, high]", length=2, item="float", unit="deg"),
    Param("light_limits_deg", "list", [10.0, 175.0], "light arm range [low, high]", length=2, item="float",
          unit="deg"),
)
#: ``plan``: explicit motor angles, or the pose planner's settings (one or the other; checked by the source).
PLAN_SCHEMA = (
    Param("angles_deg", "list", None, "explicit poses [[pan, tilt, roll, light], ...]", nullable=True, unit="deg"),
    Param("theta_d_deg", "float", None, "planner: angular sampling density", nullable=True, unit="deg"),
    Param("isotropic", "bool", True, "planner: the material is isotropic (drop azimuth-equivalent poses)"),
    Param("source", "str", "directions", "planner: plan over direction pairs or scan the motors",
          choices=("directions", "motors")),
    Param("step_deg", "float", None, "planner, source motors: motor step", nullable=True, unit="deg"),
    Param("max_theta_i_deg", "float", 75.0, "planner: largest light elevation from the normal", unit="deg"),
    Param("max_theta_r_deg", "float", 65.0, "planner: largest view elevation from the normal", unit="deg"),
)

GONIO = (
    Param("path", "str", REQUIRED, "capture folder written pose by pose (resumed if a run was interrupted), "
          "relative to the graph file", extra={"path": True}),
    Param("motors", "dict", REQUIRED, "motor name -> {device, params, axes}; joints pan, tilt, roll, light; "
          "port: sim in params starts the device's pty simulator in-process", values=MOTOR_SCHEMA),
    Param("camera", "dict", {"device": "virtual-camera", "params": {}}, "camera device {device, params}",
          schema=CAMERA_SCHEMA),
    Param("light", "dict", None, "the manifest's light section {type, intensity}; default the camera device's "
          "light_info()", nullable=True),
    Param("geometry", "dict", {}, "rig geometry (RigGeometry fields; the *_limits_deg are also the planner's "
          "limits)", schema=GEOMETRY_SCHEMA),
    Param("plan", "dict", {"theta_d_deg": 20.0, "isotropic": True},
          "poses: {angles_deg: [[pan, tilt, roll, light], ...]} or the pose planner's settings", schema=PLAN_SCHEMA),
    Param("exposures", "dict", {"times_s": [1.0]}, "exposure brackets: {times_s: [t, ...] (all poses) or "
          "[[...], ...] (per pose)} or the exposure planner {diffuse_time_s, highlight_time_s, ...}"),
    Param("read", "dict", {}, "parameters of the folder plugin that reads poses back (response, "
          "response_method, response_poses, saturation, underexposure, colour_matrix)"),
    Param("settle_s", "float", 0.0, "wait after the motors stop before photographing (arm vibration)",
          bounds=(0.0, 600.0), unit="s"),
    Param("image_format", "str", "png", "file format of 8/16-bit images (float images are always EXR)",
          choices=("png", "tif")),
    Param("durable", "bool", True, "fsync every image and journal line (crash-safe against power loss)"),
    Param("sample", "dict", None, "frame cameras: the manifest's sample section {size_mm, fiducials, ...} "
          "(the virtual camera supplies its own)", nullable=True),
    Param("intrinsics", "dict", None, "frame cameras: {K: 3x3, dist: [k1, k2, p1, p2, k3]} from a calibration",
          nullable=True),
    Param("frame_retries", "int", 1, "frame cameras: re-triggers after a frame timeout before the capture stops",
          bounds=(0, 10)),
    Param("max_saturated_fraction", "float", None, "frame cameras: stop when the shortest exposure of a pose "
          "has more than this share of pixels saturated (default: record it and mask them)", nullable=True,
          bounds=(0.0, 1.0)),
)
