"""The capture sources' parameters, declared once and read without importing the sources.

``sbrdf plugins``, graph validation and the reference docs read these through
the :class:`~sbrdf_core.plugin.PluginSpec` of each source (``__init__.py``);
the implementations (:mod:`.folder`, :mod:`.synthetic`), imported when a
graph captures, take the same tuples as their ``params``.  This module imports only
:mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import REQUIRED, Param

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
