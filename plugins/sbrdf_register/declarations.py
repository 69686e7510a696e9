"""The registrations' parameters, declared once and read without importing the registrations.

``sbrdf plugins``, graph validation and the reference docs read these through
each plugin's :class:`~sbrdf_core.plugin.PluginSpec` (``__init__.py``); the
implementations, imported when a graph uses them, take the same tuples as
their ``params``.  This module imports only :mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import Param

ARUCO = (
    Param("texels", "list", [256, 256], "texel grid [U, V] every pose is resampled onto", length=2, item="int",
          bounds=(1, 65536)),
    Param("max_rms_mm", "float", 0.5, "reject poses whose homography RMS residual on the sample plane exceeds this",
          bounds=(0.0, None), unit="mm"),
    Param("min_markers", "int", 2, "reject poses with fewer markers detected (4 corners each)", bounds=(1, None)),
    Param("max_pose_deg", "float", 10.0, "reject poses whose measured orientation differs from the nominal one "
          "by more than this; null disables the check", bounds=(0.0, 180.0), nullable=True, unit="deg"),
    Param("pose_from", "str", "fiducials", "camera pose used for ω_r: measured from the fiducials (solvePnP) "
          "or the nominal motor pose", choices=("fiducials", "nominal")),
    Param("correct_light", "bool", True, "move the nominal light into the measured sample frame (the sample, "
          "not the lab, moved)"),
    Param("corner_refine", "str", "edges", "sub-pixel corners: lines fitted to each marker's outer edges in "
          "the linear image, or OpenCV's cornerSubPix", choices=("edges", "subpix")),
    Param("refine_win_px", "int", 5, "half-size of the sub-pixel corner refinement window", bounds=(1, 64), unit="px"),
    Param("max_subsamples", "int", 4, "most bicubic sub-samples per texel axis before an extra pyramid octave "
          "of pre-blur is used", bounds=(1, 16)),
    Param("edge_margin_px", "float", 2.0, "pixels next to the sample edge that are never used (lens blur "
          "mixes in the carrier), and extra pixels kept clear of invalid pixels", bounds=(0.0, 64.0),
          unit="px"),
    Param("edge", "str", "renormalise", "texels whose filter reaches past the sample edge or the image "
          "border: renormalise (the filter is clipped to the usable pixels and its weights renormalised) "
          "or strict (the texel is invalid for that pose: the whole outer ring is lost)",
          choices=("renormalise", "strict")),
    Param("edge_min_weight", "float", 0.25, "renormalise: a clipped texel is valid when at least this "
          "fraction of its filter's weight falls on usable pixels", bounds=(0.0, 1.0)),
    Param("compiled_mapping", "bool", False, "map texels to pixels with a compiled loop (numba), the NumPy "
          "mapping's bits, instead of OpenCV's map (within a float32 ulp): no faster now (within noise "
          "at 256² texels), about 80 MB more memory in every process that registers"),
)

TEXEL_ALIGNED = (
    Param("max_rms_mm", "float", 0.5, "reject poses whose registration residual exceeds this", bounds=(0.0, None),
          unit="mm"),
)
