"""Built-in registration methods (their parameters are declared on the implementation classes)."""

from sbrdf_core.plugin import PluginSpec, hookimpl


@hookimpl
def sbrdf_registrations():
    return [
        PluginSpec(
            "texel-aligned",
            "sbrdf_register.texel_aligned:TexelAligned",
            summary="Images already on the texel grid (simulators): nominal geometry, no resampling",
        ),
        PluginSpec(
            "aruco",
            "sbrdf_register.aruco:ArucoRegistration",
            summary="ArUco fiducials: sub-pixel corners, undistortion, homography + RMS (mm), solvePnP pose, "
                    "filtered bicubic resampling onto a W×H texel grid",
        ),
    ]
