"""Built-in texture layouts."""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl


@hookimpl
def sbrdf_quantizers():
    return [
        PluginSpec(
            "linear",
            "sbrdf_quantizers.linear:LinearQuantizer",
            (Param("dtype", "str", "uint8", "texel storage type", choices=("uint8", "uint16", "float16", "float32")),),
            summary="One texture per model parameter; fixed point with per-channel scale/bias over the data range, or float",
        ),
    ]
