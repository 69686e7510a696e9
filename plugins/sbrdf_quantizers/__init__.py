"""Built-in texture layouts (see docs/textures.md) and the Mip node.  Each quantizer declares its parameters on
its class (``params``)."""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_quantizers():
    return [
        PluginSpec("linear", "sbrdf_quantizers.linear:LinearQuantizer", params=declarations.LINEAR,
                   summary="One texture per model parameter; fixed point with per-channel scale/bias over the data "
                           "range, or float"),
        PluginSpec("float-exr", "sbrdf_quantizers.float_exr:FloatEXRQuantizer", params=declarations.FLOAT_EXR,
                   summary="Float textures plus material.exr (every parameter, one multi-channel file) and "
                           "material.json"),
        PluginSpec("fixed16", "sbrdf_quantizers.fixed16:Fixed16Quantizer", params=declarations.FIXED16,
                   summary="16-bit fixed point over each channel's range; magnitudes, exponents and widths stored as "
                           "logarithms"),
        PluginSpec("mcallister8", "sbrdf_quantizers.mcallister8:McAllister8Quantizer", params=declarations.MCALLISTER8,
                   summary="McAllister's 8-bit hardware layout: rho_d RGBA8, per lobe rho_s RGB8 and (C_x, C_y, C_z, "
                           "n') RGBA8"),
        PluginSpec("palette", "sbrdf_quantizers.palette:PaletteQuantizer", params=declarations.PALETTE,
                   summary="K <= 256 representative BRDFs clustered in sampled-BRDF space; index PNG + palette "
                           "(paint round trip)"),
    ]


@hookimpl
def sbrdf_node_kinds():
    from .mip import Mip

    return [Mip]
