"""The capture sources' parameters, declared once and read without importing the sources.

``sbrdf plugins``, graph validation and the reference docs read these through
the :class:`~sbrdf_core.plugin.PluginSpec` of each source (``__init__.py``);
the implementations (:mod:`.folder`, :mod:`.synthetic`, :mod:`.gonio`,
:mod:`.virtual_folder`), imported when a graph captures, take the same tuples
as their ``params``.  The sources that drive devices (``gonio``,
``virtual-folder``) name them by plugin name, never by module: the devices
are another package's (``sbrdf_devices``), created through the registry.
This module imports only :mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import REQUIRED, Param, plugin_reference

FOLDER = (
    Param("path", "str", REQUIRED, "the capture folder (holding capture.json and images/), relative to the graph file",
          extra={"path": True}),
    Param("response", "str", "auto", "auto: the manifest's curve, else recover it from brackets; manifest: require it; "
          "recover: always recover; linear: treat pixel values as linear", choices=("auto", "manifest", "recover", "linear")),
    Param("response_method", "str", "cubic", "recovery method: McAllister's cubic in log-log space or OpenCV's Debevec (8-bit)",
          choices=("cubic", "debevec")),
    Param("response_poses", "int", 8, "bracketed poses sampled for response recovery", bounds=(1, 10000)),
    Param("saturation", "float", 0.98, "normalised level at or above which a pixel is saturated (invalid)", bounds=(0.0, 1.0)),
    Param("underexposure", "float", 0.02, "normalised level at or below which a pixel is under-exposed (invalid)",
          bounds=(0.0, 1.0)),
    Param("dark_frame", "str", None, "image inside the folder taken with no light, subtracted after linearising", nullable=True),
    Param("dark_time_s", "float", None, "exposure time of the dark frame (scaled to each exposure)", nullable=True,
          bounds=(1e-9, None), unit="s"),
    Param("colour_matrix", "list", None, "3x3 camera RGB -> working RGB matrix (row-major, 9 numbers)", nullable=True,
          length=9, item="float"),
    Param("allow_incomplete", "bool", False, "read the poses recorded so far of an interrupted capture"),
    Param("negative_tolerance", "float", 0.01, "noise tolerance for negative radiance, a fraction of full scale: a "
          "pixel below -tolerance is invalid and counted (docs/capture-folders.md)", bounds=(0.0, 1.0)),
    Param("negative_max_fraction", "float", 0.5, "a pose with more than this fraction of its pixels negative beyond "
          "the tolerance, or of its pixels above the noise floor, is an error, not noise", bounds=(0.0, 1.0)),
)

SYNTHETIC = (
    Param("texels", "list", [64, 64], "texel grid [U, V]", length=2, item="int", bounds=(1, 16384)),
    Param("size_mm", "list", [100.0, 100.0], "sample size [x, y]", length=2, item="float", bounds=(1e-3, None), unit="mm"),
    Param("poses", "int", 48, "number of light/camera poses", bounds=(1, 100000)),
    Param("model", "str", "lambert", "BRDF model the synthetic material follows", extra={"plugin_category": "brdf-model"}),
    Param("model_params", "dict", {}, "configuration of that model (e.g. lobes)", extra={"params_of": "model"}),
    Param("light_distance_mm", "float", 600.0, "light distance from the sample centre", bounds=(1.0, None), unit="mm"),
    Param("camera_distance_mm", "float", 800.0, "camera distance from the sample centre", bounds=(1.0, None), unit="mm"),
    Param("max_theta_deg", "float", 75.0, "largest light/view elevation from the normal", bounds=(0.0, 89.9), unit="deg"),
    Param("intensity", "float", None, "light radiant intensity I; default light_distance² (unit irradiance at the centre)",
          bounds=(0.0, None), nullable=True),
    Param("noise", "float", 0.0, "relative Gaussian noise on radiance (σ / L)", bounds=(0.0, None)),
    Param("saturation", "float", None, "radiance above which a pixel saturates (marked invalid)", nullable=True, bounds=(0.0, None)),
    Param("seed", "int", 0, "random seed of the noise (per pose, so resumed captures are identical)"),
    Param("pose_delay_s", "float", 0.0, "simulated exposure and motor time per pose", bounds=(0.0, 60.0), unit="s"),
)

#: ``camera`` of gonio and virtual-folder: a device and its parameters.
CAMERA_SCHEMA = plugin_reference("device", "camera")

# -- gonio: declared sub-schemas of the nested parameters (validated with paths like ``motors.arm.device``) -------

#: One entry of ``motors``.
MOTOR_SCHEMA = (
    Param("device", "str", REQUIRED, "device plugin: ptu, indexer or any device with MotorController's API",
          extra={"plugin_category": "device"}),
    Param("params", "dict", {}, "the device's parameters ({port: /dev/ttyUSB0 | sim, ...})", nullable=True),
    Param("axes", "dict", None, "joint -> driver axis; default ptu {pan: pan_deg, tilt: tilt_deg}, indexer "
          "{light: angle_deg}", nullable=True),
)
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

# -- virtual-folder -----------------------------------------------------------------------------------------------

#: ``orbit``: :func:`~sbrdf_capture.photograph.orbit_poses`'s settings.
ORBIT_SCHEMA = (
    Param("camera_distance_mm", "float", 350.0, "camera distance from the sample centre", unit="mm"),
    Param("light_distance_mm", "float", 450.0, "light distance from the sample centre", unit="mm"),
    Param("max_camera_theta_deg", "float", 50.0, "largest camera elevation from the normal", unit="deg"),
    Param("max_light_theta_deg", "float", 65.0, "largest light elevation from the normal", unit="deg"),
)

VIRTUAL_FOLDER = (
    Param("path", "str", REQUIRED, "capture folder to write (resumed if a run was interrupted, re-rendered if this source "
          "wrote it with other parameters), relative to the graph file", extra={"path": True}),
    Param("camera", "dict", {"device": "virtual-camera", "params": {}},
          "camera device {device, params}: the virtual-camera's parameters (size, focal_px, model, texels, effects, ...)",
          schema=CAMERA_SCHEMA),
    Param("poses", "int", 60, "number of poses: camera and light on two Fibonacci spirals over the hemisphere "
          "(sbrdf_capture.photograph.orbit_poses)", bounds=(1, 100000)),
    Param("orbit", "dict", {}, "orbit_poses settings: camera_distance_mm (350), light_distance_mm (450), "
          "max_camera_theta_deg (50), max_light_theta_deg (65)", schema=ORBIT_SCHEMA),
    Param("exposures", "list", [1.0], "exposure times in s: one bracket of 1-3 times for every pose, e.g. [0.25, 1.0], "
          "or one bracket per pose [[...], ...]"),
    Param("light", "dict", None, "the manifest's light section {type, intensity}; default the camera's light_info()",
          nullable=True),
    Param("read", "dict", {}, "parameters of the folder plugin that reads the folder back (response, saturation, "
          "underexposure, colour_matrix, ...)"),
    Param("image_format", "str", "png", "file format of 8/16-bit images (float images are always EXR)",
          choices=("png", "tif")),
    Param("durable", "bool", True, "fsync every image and journal line (crash-safe against power loss)"),
)
