"""The devices' parameters, declared once and read without importing a driver.

``sbrdf plugins``, graph validation and the reference docs read these through
the :class:`~sbrdf_core.plugin.PluginSpec` of each device (``__init__.py``);
the drivers (:mod:`.motors.ptu`, :mod:`.motors.indexer`,
:mod:`.cameras.virtual`, :mod:`.cameras.pylon`, :mod:`.cameras.aravis`,
:mod:`.cameras.genicam`, :mod:`.cameras.uvc`, :mod:`.cameras.gphoto`),
imported when a capture opens a device, take the same tuples as their
``params``.  This module imports only :mod:`sbrdf_core.params`,
:mod:`sbrdf_lib.serial_params` and :mod:`sbrdf_lib.camera_params` (no
pyserial, camera SDK, OpenCV or NumPy).
"""

from __future__ import annotations

from sbrdf_core.params import Param
from sbrdf_lib.camera_params import COMMON_PARAMS
from sbrdf_lib.serial_params import LINK_PARAMS

# -- motor controllers (motors/) ----------------------------------------------------------------------------------

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

# -- cameras (cameras/) -------------------------------------------------------------------------------------------

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
