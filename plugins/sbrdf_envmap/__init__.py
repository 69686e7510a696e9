"""Environment lighting for spatially varying BRDFs (seed 000 §6.9–6.10, seed 004 §4.4).

The ``environment`` scene effect: an EXR environment (lat-long or cube) as a
cube map with a MIP chain, lighting every texel of every material through
McAllister's prefiltered maps (D(N) and S(ω_p, n), Eq 6.18), Mühlbacher's
deterministic filtered in-lobe sampling (Eqs 4.10–4.25), or Monte Carlo
(the cpu reference, progressive in gl).  Renderers consult it only when a
scene has ``environment:``.  See ``docs/environment-lighting.md``.
"""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

#: The scene keys the effects read: the ``environment:`` section and planes' ``reflector:`` flag.
ENVIRONMENT = (
    Param("file", "str", doc="EXR environment map, relative to the scene file", extra={"path": True}),
    Param("layout", "str", "latlong", "map layout", choices=("latlong", "cube")),
    Param("intensity", "float", 1.0, "radiance scale", bounds=(0.0, None)),
    Param("options", "dict", {}, "options of the environment scene effect (docs/environment-lighting.md)"),
)


@hookimpl
def sbrdf_scene_keys():
    return {
        "scene": (Param("environment", "dict", None, "an environment map lighting the scene (the environment scene "
                        "effect, docs/environment-lighting.md)", nullable=True, schema=ENVIRONMENT,
                        extra={"light": True}),),
        "object.plane": (Param("reflector", "bool", False, "a planar reflector: its specular lobes reflect the other "
                               "objects (the mirror scene effect, docs/environment-lighting.md)"),),
    }


@hookimpl
def sbrdf_scene_effects():
    return [PluginSpec("environment", "sbrdf_envmap.effect:EnvironmentEffect",
                       summary="Environment maps: McAllister's prefiltered maps, Muehlbacher's deterministic "
                               "in-lobe sampling, Monte Carlo reference"),
            PluginSpec("mirror", "sbrdf_envmap.mirror:MirrorEffect",
                       summary="Planar reflectors (reflector: true planes): Muehlbacher's mirrored-camera buffer "
                               "with tangent-plane projection; ray-cast Monte Carlo reference in cpu")]
