"""Built-in registration methods (their parameters are declared on the implementation classes)."""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_registrations():
    return [
        PluginSpec(
            "texel-aligned",
            "sbrdf_register.texel_aligned:TexelAligned", params=declarations.TEXEL_ALIGNED,
            summary="Images already on the texel grid (simulators): nominal geometry, no resampling",
        ),
        PluginSpec(
            "aruco",
            "sbrdf_register.aruco:ArucoRegistration", params=declarations.ARUCO,
            summary="ArUco fiducials: sub-pixel corners, undistortion, homography + RMS (mm), solvePnP pose, "
                    "filtered bicubic resampling onto a W×H texel grid",
        ),
    ]
