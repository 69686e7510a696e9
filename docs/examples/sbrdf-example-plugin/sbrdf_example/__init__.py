"""Manifest of the example plugin: what it contributes, nothing imported eagerly.

sbrdf imports this module (the ``sbrdf`` entry point in ``pyproject.toml``)
when its registry loads, and calls each hook below once.  The hooks return
:class:`~sbrdf_core.plugin.PluginSpec` s: a registry name, the import path of
the implementation (imported only when a graph uses it), its parameters and a
summary.  The parameters are declared once, in :mod:`.declarations`, which
imports only ``sbrdf_core.params``; the specs carry them and the classes take
the same tuples (``Turntable.params = TURNTABLE``), so the graph validator,
``sbrdf plugins`` and the graph reference (docs/reference/graph.md) all read
that one declaration without importing the driver, the effect or pyserial.
The package imports only ``sbrdf_core`` and ``sbrdf_lib``, sbrdf's public layers.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations

__version__ = "0.2.0"


@hookimpl
def sbrdf_brdf_models():
    return [
        PluginSpec("minnaert", "sbrdf_example.minnaert:MinnaertModel", params=(),
                   summary="Minnaert's limb-darkening diffuse model, f_r = rho_d (cos θi cos θo)^(k-1)"),
    ]


@hookimpl
def sbrdf_devices():
    return [
        PluginSpec("turntable", "sbrdf_example.turntable:Turntable", params=declarations.TURNTABLE,
                   summary="Rotary stage over serial, three-command ASCII protocol (G, Q, S); pty simulator included"),
    ]


@hookimpl
def sbrdf_scene_effects():
    return [
        PluginSpec("ambient", "sbrdf_example.ambient:AmbientEffect", params=declarations.AMBIENT,
                   summary="Uniform sky fill light, L += pi A f_r(n, wo); scenes ask with effects: {ambient: {...}}"),
    ]
