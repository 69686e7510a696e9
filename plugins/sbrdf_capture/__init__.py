"""Built-in capture sources."""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

SYNTHETIC_PARAMS = (
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


@hookimpl
def sbrdf_captures():
    return [
        PluginSpec(
            "synthetic",
            "sbrdf_capture.synthetic:SyntheticCapture",
            SYNTHETIC_PARAMS,
            summary="Simulated texel-aligned capture of a procedural material of any BRDF model",
        ),
    ]
