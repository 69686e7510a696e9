"""The camera devices' and the virtual-folder source's parameters, read without importing them.

``sbrdf plugins``, graph validation and the reference docs read these through
the :class:`~sbrdf_core.plugin.PluginSpec` of each contribution
(``__init__.py``); the implementations (:mod:`.virtual`, :mod:`.pylon`,
:mod:`.aravis`, :mod:`.genicam`, :mod:`.uvc`, :mod:`.gphoto`, :mod:`.capture`), imported when
a graph opens a camera, take the same tuples as their ``params``.  This module
imports only :mod:`sbrdf_core.params` and :mod:`sbrdf_lib.camera_params` (no
camera SDK, OpenCV or NumPy).
"""

from __future__ import annotations

from sbrdf_core.params import REQUIRED, Param, plugin_reference
from sbrdf_lib.camera_params import COMMON_PARAMS

#: The virtual camera's effects, in the order they are applied.
EFFECTS = ("falloff", "vignetting", "blur", "motor_error", "dark_current", "black_level", "noise", "saturation",
           "response", "shadowing", "masking")
#: ``mesostructure``'s keys (:class:`sbrdf_lib.mesostructure.Mesostructure`).
MESOSTRUCTURE_SCHEMA = (
    Param("height_mm", "any", 0.0, "height field: a number, a .npy path (V, U) or {procedural: bumps|ridges|noise, ...}",
          unit="mm"),
    Param("albedo", "any", 0.8, "per-texel albedo: a number, [r, g, b], a .npy path (V, U[, 3]) or {procedural: ...}"),
    Param("facet", "str", "lambert", "each facet reflects Lambertian, or with the camera's BRDF model",
          choices=("lambert", "model")),
)

#: ``camera``: a device and its parameters.
CAMERA_SCHEMA = plugin_reference("device", "camera")
#: ``orbit``: :func:`~sbrdf_cameras.virtual.orbit_poses`'s settings.
ORBIT_SCHEMA = (
    Param("camera_distance_mm", "float", 350.0, "camera distance from the sample centre", unit="mm"),
    Param("light_distance_mm", "float", 450.0, "light distance from the sample centre", unit="mm"),
    Param("max_camera_theta_deg", "float", 50.0, "largest camera elevation from the normal", unit="deg"),
    Param("max_light_theta_deg", "float", 65.0, "largest light elevation from the normal", unit="deg"),
)

PYLON = COMMON_PARAMS + (
    Param("width", "int", None, "region of interest width from the left edge", nullable=True, bounds=(1, 65536),
          unit="px"),
    Param("height", "int", None, "region of interest height from the top edge", nullable=True,
          bounds=(1, 65536), unit="px"),
    Param("emulation_frames", "str", None, "emulated camera only: image file pattern with {pose} and {exposure} "
          "fields served as the frames", nullable=True),
)

ARAVIS = COMMON_PARAMS + (
    Param("width", "int", None, "region of interest width from the left edge", nullable=True, bounds=(1, 65536),
          unit="px"),
    Param("height", "int", None, "region of interest height from the top edge", nullable=True,
          bounds=(1, 65536), unit="px"),
    Param("buffers", "int", 4, "stream buffers queued for the camera", bounds=(1, 256)),
)

GENICAM = COMMON_PARAMS + (
    Param("producer", "str", None, "GenTL producer of the camera's interface, the vendor's .cti file; default every "
          ".cti in the folders of GENICAM_GENTL64_PATH", nullable=True, extra={"path": True}),
    Param("width", "int", None, "region of interest width from the left edge", nullable=True, bounds=(1, 65536),
          unit="px"),
    Param("height", "int", None, "region of interest height from the top edge", nullable=True,
          bounds=(1, 65536), unit="px"),
    Param("buffers", "int", 4, "buffers the producer fills for the driver", bounds=(1, 256)),
)

UVC = COMMON_PARAMS + (
    Param("source", "str", "0", "device index, device path, or a video file / image sequence pattern"),
    Param("exposure_range_s", "list", [1e-4, 1.0], "[shortest, longest] exposure the device accepts", length=2,
          item="float", unit="s"),
    Param("width", "int", None, "capture width asked of the device", nullable=True, bounds=(1, 16384), unit="px"),
    Param("height", "int", None, "capture height asked of the device", nullable=True, bounds=(1, 16384),
          unit="px"),
    Param("flush_frames", "int", 2, "frames discarded before the one kept (a free-running camera's queue)",
          bounds=(0, 100)),
)

GPHOTO = COMMON_PARAMS[:5] + (
    Param("timeout_s", "float", 30.0, "frame timeout after the exposure", bounds=(1e-3, 3600.0), unit="s"),
    COMMON_PARAMS[6],
    Param("iso", "str", None, "ISO setting, one of the camera's choices", nullable=True),
    Param("keep_on_camera", "bool", False, "leave each file on the card after downloading it"),
)

VIRTUAL = (
    Param("width", "int", 1024, "image width", bounds=(8, 16384), unit="px"),
    Param("height", "int", 768, "image height", bounds=(8, 16384), unit="px"),
    Param("focal_px", "float", 1400.0, "focal length in pixels (fx = fy)", bounds=(1.0, None), unit="px"),
    Param("principal_point", "list", None, "[cx, cy]; default the image centre", length=2, item="float", nullable=True, unit="px"),
    Param("dist", "list", [-0.08, 0.02, 0.0, 0.0, 0.0], "OpenCV distortion coefficients [k1, k2, p1, p2, k3]",
          length=5, item="float"),
    Param("sample_size_mm", "list", [100.0, 100.0], "sample area [x, y] inside the fiducial border", length=2, item="float",
          bounds=(1e-3, None), unit="mm"),
    Param("texels", "list", [256, 256], "texel grid [U, V] of the procedural material", length=2, item="int", bounds=(1, 16384)),
    Param("model", "str", "lambert", "BRDF model of the procedural material", extra={"plugin_category": "brdf-model"}),
    Param("model_params", "dict", {}, "configuration of that model", extra={"params_of": "model"}),
    Param("param_maps", "str", None, "path of a ParamMaps artifact to photograph instead (its model and maps)", nullable=True),
    Param("carrier_margin_mm", "float", 20.0, "width of the printed border band around the sample", bounds=(1.0, None), unit="mm"),
    Param("marker_size_mm", "float", 14.0, "ArUco marker side", bounds=(1.0, None), unit="mm"),
    Param("markers_per_side", "int", 3, "markers per side of the border (4x this in all)", bounds=(1, 64)),
    Param("dictionary", "str", "DICT_4X4_50", "cv2.aruco predefined dictionary of the markers"),
    Param("intensity", "float", 250000.0, "point-light radiant intensity I (relative W/sr)", bounds=(0.0, None)),
    Param("sensitivity", "float", 1.0, "signal per unit radiance and second; signal 1 saturates", bounds=(1e-12, None)),
    Param("effects", "list", [], f"effects to simulate, any of {list(EFFECTS)}; none are computed unless listed",
          item="str"),
    Param("response_curve", "str", "srgb", "response effect: camera curve", choices=("gamma", "srgb", "cubic")),
    Param("response_gamma", "float", 2.2, "response_curve gamma: g(z) = z^gamma", bounds=(0.1, 10.0)),
    Param("response_coefficients", "list", [2.0, -0.05, -0.01], "response_curve cubic: log X = a1 y + a2 y² + a3 y³, y = log z",
          length=3, item="float"),
    Param("bit_depth", "int", 8, "response effect: bits per channel", choices=(8, 16)),
    Param("record_response", "bool", True, "write the response table into capture.json (else readers recover it from brackets)"),
    Param("full_well", "float", 20000.0, "noise effect: electrons at saturation (shot noise)", bounds=(1.0, None)),
    Param("read_noise", "float", 0.001, "noise effect: read noise σ as a fraction of saturation", bounds=(0.0, None)),
    Param("dark_current", "float", 0.002, "dark_current effect: mean dark signal per second (fraction of saturation)",
          bounds=(0.0, None), unit="1/s"),
    Param("black_level", "float", 0.02, "black_level effect: mean pedestal of every frame (fraction of saturation)",
          bounds=(0.0, 0.5)),
    Param("vignetting_power", "float", 4.0, "vignetting effect: factor cos^p of the off-axis angle", bounds=(0.0, 16.0)),
    Param("motor_rotation_deg", "float", 0.786, "motor_error effect: σ of the sample rotation (PTU-46-70 repeatability)",
          bounds=(0.0, 45.0), unit="deg"),
    Param("motor_light_mm", "float", 2.462, "motor_error effect: σ of the light position offset", bounds=(0.0, None), unit="mm"),
    Param("blur_px", "float", 0.7, "blur effect: Gaussian lens-blur σ", bounds=(0.0, 50.0), unit="px"),
    Param("seed", "int", 0, "seed of every random effect (per pose and exposure)"),
    Param("row_chunk", "int", 128, "image rows rendered at once (bounds memory)", bounds=(1, 16384)),
    Param("carrier_supersample", "int", 4, "rays per pixel side over the printed carrier (pixel-area integration of the "
          "fiducials; 1 = point sampling)", bounds=(1, 16)),
    Param("mesostructure", "dict", None, "photograph a height field with per-texel albedo instead of a flat sample: "
          "{height_mm, albedo, facet} (sbrdf_lib.mesostructure); effects shadowing/masking act on it",
          nullable=True, schema=MESOSTRUCTURE_SCHEMA),
)

VIRTUAL_FOLDER = (
    Param("path", "str", REQUIRED, "capture folder to write (resumed if a run was interrupted, re-rendered if this source "
          "wrote it with other parameters), relative to the graph file", extra={"path": True}),
    Param("camera", "dict", {"device": "virtual-camera", "params": {}},
          "camera device {device, params}: the virtual-camera's parameters (size, focal_px, model, texels, effects, ...)",
          schema=CAMERA_SCHEMA),
    Param("poses", "int", 60, "number of poses: camera and light on two Fibonacci spirals over the hemisphere "
          "(sbrdf_cameras.virtual.orbit_poses)", bounds=(1, 100000)),
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
