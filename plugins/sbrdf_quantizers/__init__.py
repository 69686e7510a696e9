"""Built-in texture layouts (see docs/textures.md)."""

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
        PluginSpec(
            "float-exr",
            "sbrdf_quantizers.float_exr:FloatEXRQuantizer",
            (Param("dtype", "str", "float16", "float32 (exact) or half float", choices=("float16", "float32")),
             Param("colour_space", "str", "mcallister", "linear RGB primaries the material is in (recorded in the JSON)",
                   choices=("mcallister", "rec709", "rec2020"))),
            summary="Float textures plus material.exr (every parameter, one multi-channel file) and material.json",
        ),
        PluginSpec(
            "fixed16",
            "sbrdf_quantizers.fixed16:Fixed16Quantizer",
            (Param("canonical", "bool", False, "store the model's canonical parameters (Lafortune: C_z = 1)"),),
            summary="16-bit fixed point over each channel's range; magnitudes, exponents and widths stored as logarithms",
        ),
        PluginSpec(
            "mcallister8",
            "sbrdf_quantizers.mcallister8:McAllister8Quantizer",
            (Param("rescale", "str", "max", "per-texel rho_s/C gauge: max(rho_s) = 1, min(rho_s) = min|C|, or as fitted",
                   choices=("max", "balanced", "none")),
             Param("c_range", "float", 1.0, "C biased over -1..1 (7 bits) or -2..2 (6 bits, keeps |C| > 1)",
                   choices=(1.0, 2.0)),
             Param("alpha", "str", None, "transparency mask: a PNG of the texel grid (0 = cut away) stored as "
                   "rho_d's alpha; relative to the graph file", nullable=True, extra={"path": True})),
            summary="McAllister's 8-bit hardware layout: rho_d RGBA8, per lobe rho_s RGB8 and (C_x, C_y, C_z, n') RGBA8",
        ),
        PluginSpec(
            "palette",
            "sbrdf_quantizers.palette:PaletteQuantizer",
            (Param("k", "int", 256, "palette entries at most (8-bit index)", bounds=(1, 256)),
             Param("directions", "int", 12, "Fibonacci directions per side of the sampled-BRDF vectors", bounds=(2, 64)),
             Param("seed", "int", 0, "k-means seed")),
            summary="K <= 256 representative BRDFs clustered in sampled-BRDF space; index PNG + palette (paint round trip)",
        ),
    ]


@hookimpl
def sbrdf_node_kinds():
    from .mip import Mip

    return [Mip]
