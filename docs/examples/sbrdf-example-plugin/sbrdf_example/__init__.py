"""Manifest of the example plugin: what it contributes, nothing imported eagerly.

sbrdf imports this module (the ``sbrdf`` entry point in ``pyproject.toml``)
when its registry loads, and calls each hook below once.  The hooks return
:class:`~sbrdf_core.plugin.PluginSpec` s: a registry name, the import path of
the implementation (imported only when a graph uses it), and its parameters,
declared once here; the graph validator, ``sbrdf plugins`` and the graph
reference (docs/reference/graph.md) all read them from these declarations.
"""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

__version__ = "0.2.0"

TURNTABLE_PARAMS = (
    Param("port", "str", doc="serial device path (/dev/ttyUSB0, a simulator's pty); `sim` in a gonio graph"),
    Param("baudrate", "int", 19200, "line speed", choices=(9600, 19200, 38400, 115200)),
    Param("timeout_s", "float", 1.0, "how long to wait for a complete reply", bounds=(0.001, 60.0), unit="s"),
    Param("retries", "int", 3, "extra attempts after a dropped/garbled reply or a missed position", bounds=(0, 20)),
    Param("tolerance_deg", "float", 0.01, "largest accepted difference between target and read-back angle",
          bounds=(0.0, 10.0), unit="deg"),
    Param("limits_deg", "list", [-180.0, 180.0], "soft limits [low, high]; moves outside are refused unsent",
          length=2, item="float", bounds=(-720.0, 720.0), unit="deg"),
    Param("move_timeout_s", "float", 60.0, "longest a single move may take", bounds=(0.01, 3600.0), unit="s"),
    Param("poll_s", "float", 0.005, "status polling interval while the stage moves", bounds=(0.0, 1.0), unit="s"),
)

AMBIENT_PARAMS = (
    Param("radiance", "list", [0.1, 0.1, 0.1], "sky radiance (RGB) arriving from every direction above the surface",
          length=3, item="float", bounds=(0.0, None)),
)


@hookimpl
def sbrdf_brdf_models():
    return [
        PluginSpec("minnaert", "sbrdf_example.minnaert:MinnaertModel",
                   summary="Minnaert's limb-darkening diffuse model, f_r = rho_d (cos θi cos θo)^(k-1)"),
    ]


@hookimpl
def sbrdf_devices():
    return [
        PluginSpec("turntable", "sbrdf_example.turntable:Turntable", TURNTABLE_PARAMS,
                   summary="Rotary stage over serial, three-command ASCII protocol (G, Q, S); pty simulator included"),
    ]


@hookimpl
def sbrdf_scene_effects():
    return [
        PluginSpec("ambient", "sbrdf_example.ambient:AmbientEffect", AMBIENT_PARAMS,
                   summary="Uniform sky fill light, L += pi A f_r(n, wo); scenes ask with effects: {ambient: {...}}"),
    ]
