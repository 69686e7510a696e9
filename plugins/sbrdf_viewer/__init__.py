"""The viewers: ``sbrdf view RUN/NODE`` writes one self-contained HTML page of a fitted or quantized SBRDF
(WebGL2, the models' own GLSL) and serves it on localhost; ``sbrdf plot`` draws McAllister's SBRDF viewer
(spatial image, exitant hemisphere, incidence plane) as PNG files.

Why a plugin: the viewer needs nothing the engine does not already give (the material loader, the models' GLSL
through the registry), and a command contributed through ``sbrdf_commands`` can be disabled (``-p no:viewer``) or
replaced like any other plugin.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl


@hookimpl
def sbrdf_commands():
    return [PluginSpec("view", "sbrdf_viewer.command:ViewCommand",
                       summary="write a self-contained WebGL2 page of a fitted or quantized SBRDF and serve it on localhost"),
            PluginSpec("plot", "sbrdf_viewer.command:PlotCommand",
                       summary="the SBRDF viewer: spatial image, exitant hemisphere, incidence-plane plot (PNG)")]
