"""Environment lighting for spatially varying BRDFs (seed 000 §6.9–6.10, seed 004 §4.4).

The ``environment`` scene effect: an EXR environment (lat-long or cube) as a
cube map with a MIP chain, lighting every texel of every material through
McAllister's prefiltered maps (D(N) and S(ω_p, n), Eq 6.18), Mühlbacher's
deterministic filtered in-lobe sampling (Eqs 4.10–4.25), or Monte Carlo
(the cpu reference, progressive in gl).  Renderers consult it only when a
scene has ``environment:``.  See ``docs/environment-lighting.md``.

The effects' options are declared here, once, so listing and validating read
them without importing the effects; the effect classes take the same tuples.
"""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

#: Options of the ``environment`` scene effect: the ``options:`` of the scene's ``environment:`` section.
ENVIRONMENT_OPTIONS = (
    Param("method", "str", "prefiltered-discrete", "prefiltered-discrete | prefiltered-mip (McAllister Eq 6.18), "
          "sampling (Muehlbacher's deterministic in-lobe samples), mc (cpu Monte Carlo reference), progressive "
          "(gl: mc_samples per frame, running mean over frames)",
          choices=("prefiltered-discrete", "prefiltered-mip", "sampling", "mc", "progressive")),
    Param("size", "int", 32, "cube face size of the environment (power of two); its MIP chain feeds sampling",
          bounds=(1, 4096)),
    Param("prefiltered_size", "int", 32, "face size of the specular maps S(., n) (MIP form: of n = 256)",
          bounds=(1, 4096)),
    Param("diffuse_size", "int", 16, "face size of the diffuse map D(N)", bounds=(1, 4096)),
    Param("cosine", "str", "normalized", "Eq 6.18's cosine: N.p/|p| clamped at 0 (normalized) or the printed N.p "
          "(literal)", choices=("normalized", "literal")),
    Param("prefilter", "str", "auto", "where the maps are convolved: gl (a fragment pass), numpy (the float64 "
          "reference integrator), auto (gl in the gl renderer, numpy in cpu)", choices=("auto", "gl", "numpy")),
    Param("samples", "int", 7, "deterministic samples per lobe (Table 4.1: 3 to 19)", bounds=(1, 64)),
    Param("estimator", "str", "4.25", "ratio estimator of the deterministic samples (Eq 4.23, 4.24 or 4.25)",
          choices=("4.23", "4.24", "4.25")),
    Param("xi_border", "float", 0.01, "lobe cut: the importance-sampling mass left outside the pattern",
          bounds=(1e-6, 0.5)),
    Param("ring_radius", "float", 0.6, "xi_1 of the ring (theta_h = 0.4 theta_thresh)", bounds=(0.0, 1.0)),
    Param("line_threshold", "float", 4.0, "m_y/m_x (or m_x/m_y) above which the line pattern replaces the ring "
          "(not given in the thesis)", bounds=(1.0, None)),
    Param("mc_samples", "int", 64, "Monte Carlo samples per strategy and pixel (per frame when progressive)",
          bounds=(1, 1 << 20)),
    Param("seed", "int", 0, "seed of the scrambled Sobol points", bounds=(0, None)),
)

#: Options of the ``mirror`` scene effect: the scene's ``mirror:`` section, validated by the scene loader.
MIRROR_PARAMS = (
    Param("samples", "int", 7, "deterministic samples per lobe (Table 4.2: 3 to 19)", bounds=(1, 64)),
    Param("estimator", "str", "4.25", "ratio estimator (Eq 4.23, 4.24 or 4.25)", choices=("4.23", "4.24", "4.25")),
    Param("xi_border", "float", 0.01, "lobe cut: the importance-sampling mass left outside the pattern",
          bounds=(1e-6, 0.5)),
    Param("ring_radius", "float", 0.6, "xi_1 of the ring (theta_h = 0.4 theta_thresh)", bounds=(0.0, 1.0)),
    Param("line_threshold", "float", 4.0, "m_y/m_x (or m_x/m_y) above which the line pattern replaces the ring",
          bounds=(1.0, None)),
    Param("refinements", "int", 1, "tangent-plane refinement steps of the projection (the thesis: 1)", bounds=(0, 8)),
    Param("mc_samples", "int", 64, "cpu reference: Monte Carlo samples per strategy and pixel", bounds=(1, 1 << 20)),
    Param("seed", "int", 0, "seed of the scrambled Sobol points", bounds=(0, None)),
)

#: Options of the ``cubemaps`` scene effect: the scene's ``cube_maps:`` section.
CUBE_MAP_PARAMS = tuple(p for p in MIRROR_PARAMS if p.name != "refinements")

#: One object's ``cube_map:`` (Mühlbacher §4.4.1): where its incident-light cube map is rendered and corrected.
CUBE_MAP = (
    Param("size", "int", 64, "face size of the object's cube map (power of two); it gets a MIP chain",
          bounds=(4, 2048)),
    Param("centre", "list", None, "where the cube map is rendered; default: the object's bounding-box centre",
          nullable=True, length=3, item="float"),
    Param("planes", "list", [], "bounding planes [a, b, c, d] (a x + b y + c z = d; at least two, e.g. floor and "
          "ceiling) for the parallax correction: a sample's look-up direction runs from the centre to the nearest "
          "plane its ray hits (Fig 4.5)"),
    Param("parallax", "bool", True, "correct look-ups with the planes (false: the environment-at-infinity look-up)"),
)

#: The scene keys the effects read: the ``environment:``, ``mirror:`` and ``cube_maps:`` sections, planes'
#: ``reflector:`` flag and every object's ``cube_map:``.
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
                        extra={"light": True}),
                  Param("mirror", "dict", None, "options of the planar reflectors (the mirror scene effect; planes with "
                        "reflector: true, docs/environment-lighting.md)", nullable=True, schema=MIRROR_PARAMS),
                  Param("cube_maps", "dict", None, "options of the per-object cube maps (the cubemaps scene effect; "
                        "objects with cube_map:, docs/walkthrough.md)", nullable=True, schema=CUBE_MAP_PARAMS)),
        "object": (Param("cube_map", "dict", None, "an incident-light cube map of the rest of the scene for this "
                         "object's specular lobes (the cubemaps scene effect, docs/walkthrough.md)", nullable=True,
                         schema=CUBE_MAP),),
        "object.plane": (Param("reflector", "bool", False, "a planar reflector: its specular lobes reflect the other "
                               "objects (the mirror scene effect, docs/environment-lighting.md)"),),
    }


@hookimpl
def sbrdf_scene_effects():
    return [PluginSpec("environment", "sbrdf_envmap.effect:EnvironmentEffect", params=ENVIRONMENT_OPTIONS,
                       summary="Environment maps: McAllister's prefiltered maps, Muehlbacher's deterministic "
                               "in-lobe sampling, Monte Carlo reference"),
            PluginSpec("cubemaps", "sbrdf_envmap.cubemaps:CubeMapEffect", params=CUBE_MAP_PARAMS,
                       summary="Per-object cube maps (cube_map: on an object): the diffuse scene rendered at its "
                               "centre, bounding-plane parallax correction, deterministic in-lobe samples"),
            PluginSpec("mirror", "sbrdf_envmap.mirror:MirrorEffect", params=MIRROR_PARAMS,
                       summary="Planar reflectors (reflector: true planes): Muehlbacher's mirrored-camera buffer "
                               "with tangent-plane projection; ray-cast Monte Carlo reference in cpu")]
