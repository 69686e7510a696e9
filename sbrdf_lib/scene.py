"""Scene files: what a renderer draws, and so what it must simulate.

A scene is a YAML file naming geometry, materials, lights, an optional
environment map and a camera (``docs/scenes.md``)::

    camera: {position: [0, -3, 2], look_at: [0, 0, 0], fov_deg: 40, resolution: [800, 600]}
    materials:
      sample: {artifact: input}                 # the Render node's input (the default)
      paint:  {model: phong, params: {rho_d: [0.2, 0.1, 0.1], rho_s: [0.5, 0.5, 0.5], exponent: 40}}
    objects:
      - {shape: plane, size: [2, 2], material: sample}
      - {shape: sphere, radius: 0.5, material: paint, transform: {translate: [1, 0, 0.5]}}
      - {shape: mesh, file: bunny.obj, material: sample}
    lights:
      - {type: point, position: [2, -2, 3], intensity: 10, falloff: true}
      - {type: directional, direction: [0, 0, 1], irradiance: [1, 0.9, 0.8]}
    shadows: false
    antialias: 4          # samples per pixel, n² (2×2 here; 1 = off); the default

Every key is declared once as :class:`~sbrdf_core.params.Param` data, so an
unknown key, a wrong type or a missing value is reported with the scene
file's line, like graphs.  The keys below are the renderers' own; plugins add
theirs through the ``sbrdf_scene_keys`` hook (:func:`plugin_keys`): a
top-level section (``environment:``), material keys (``shading_map:``) or
object keys (``reflector:``).  Renderers read :func:`Scene.features` to decide
which effects (and which shader code) the scene needs.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import yaml

from sbrdf_core import _yaml, input_files
from sbrdf_core.contracts import optional
from sbrdf_core.errors import Problem, SbrdfError
from sbrdf_core.params import Param, resolve

from .mesh import FORMATS as MESH_FORMATS
from .mesh import load_mesh, mesh_files, mesh_vertex_radius

__all__ = ["ANTIALIAS_DEFAULT", "ANTIALIAS_MAX", "AREA_LIGHT", "CAMERA", "CAMERA_PATH", "DISPLAY", "KEYFRAME", "LIGHTMAP",
           "LIGHTS", "MATERIAL", "OBJECT", "SHAPES", "TOP_KEYS", "TRANSFORM", "Camera", "Features", "Light", "MaterialRef", "PluginKeys", "Scene",
           "SceneError", "SceneObject", "downsample", "load_scene", "plugin_keys", "reference", "rgb", "scene_fingerprint",
           "transform_matrix"]

logger = logging.getLogger(__name__)

CAMERA = (
    Param("position", "list", [0.0, -3.0, 2.0], "eye position", length=3, item="float"),
    Param("look_at", "list", [0.0, 0.0, 0.0], "point at the centre of the image", length=3, item="float"),
    Param("up", "list", [0.0, 0.0, 1.0], "world direction that appears upwards", length=3, item="float"),
    Param("fov_deg", "float", 40.0, "vertical field of view", bounds=(1.0, 170.0), unit="deg"),
    Param("resolution", "list", [800, 600], "image width and height in pixels", length=2, item="int", bounds=(1, 16384)),
)

TRANSFORM = (
    Param("translate", "list", [0.0, 0.0, 0.0], "translation, applied last", length=3, item="float"),
    Param("rotate_deg", "list", [0.0, 0.0, 0.0], "rotations about x, then y, then z", length=3, item="float", unit="deg"),
    Param("scale", "float", 1.0, "uniform scale, applied first", bounds=(1e-9, None)),
)

OBJECT = (
    Param("shape", "str", choices=("plane", "sphere", "cylinder", "mesh"), doc="geometry"),
    Param("material", "str", "sample", "name of an entry of materials:"),
    Param("transform", "dict", {}, "placement: translate, rotate_deg, scale"),
    Param("uv_repeat", "list", [1.0, 1.0], "texture repeats across the surface in u and v", length=2, item="float",
          bounds=(1e-6, None)),
)

#: Shape-specific keys.  Built-in shapes are centred at the origin with +z up.
SHAPES = {
    "plane": (Param("size", "list", [1.0, 1.0], "extent in x and y (u runs along +x, v along +y)", length=2, item="float",
                    bounds=(1e-9, None)),),
    "sphere": (Param("radius", "float", 0.5, "radius", bounds=(1e-9, None)),
               Param("segments", "list", [128, 64], "GL tessellation in longitude and latitude", length=2, item="int",
                     bounds=(3, 4096))),
    "cylinder": (Param("radius", "float", 0.5, "radius", bounds=(1e-9, None)),
                 Param("height", "float", 1.0, "extent along z (no caps)", bounds=(1e-9, None)),
                 Param("segments", "int", 128, "GL tessellation around the axis", bounds=(3, 4096))),
    "mesh": (Param("file", "str", doc="triangle mesh (OBJ, PLY, glTF or GLB), relative to the scene file"),
             Param("uv_layout", "str", "auto", "texture coordinates of a mesh whose file has none: planar (projected "
                   "onto its xy bounds), chart (each triangle its own atlas place: what a light map needs), auto "
                   "(chart when the scene has lightmap:, else planar)", choices=("auto", "planar", "chart"))),
}

MATERIAL = (
    Param("artifact", "str", None, "'input' (the Render node's material), or the path of a ParamMaps or TextureSet "
          "store relative to the scene file", nullable=True),
    Param("model", "str", None, "a BRDF-model plugin, for a uniform material given by params:", nullable=True),
    Param("model_params", "dict", {}, "configuration of that model (e.g. {lobes: 2})"),
    Param("params", "dict", {}, "the model's parameter values (scalars or RGB triples)"),
    Param("filter", "str", "bilinear", "parameter-map lookup; trilinear blends two MIP levels (a Mip node's "
          "levels) chosen by the pixel's texel footprint, and is bilinear on a material without levels",
          choices=("nearest", "bilinear", "trilinear")),
)

LIGHTS = {
    "point": (Param("position", "list", doc="light position", length=3, item="float"),
              Param("intensity", "any", 1.0, "radiant intensity I (a number or an RGB triple)"),
              Param("falloff", "bool", True, "inverse-square fall-off: E = I cos θ / d²; false: E = I cos θ")),
    "directional": (Param("direction", "list", doc="direction towards the light", length=3, item="float"),
                    Param("irradiance", "any", 1.0, "irradiance at normal incidence (a number or an RGB triple)")),
}

DISPLAY = (
    Param("exposure", "float", None, "linear scale before display; default maps the 99th percentile to 0.8",
          nullable=True, bounds=(0.0, None)),
    Param("gamma", "str", "srgb", "display transfer of the PNG", choices=("srgb", "2.2")),
)

#: ``lightmap:``: per-object irradiance maps (Mühlbacher §4.3, Eq 4.1), baked by ``sbrdf_lightmap``; renderers
#: then shade diffuse as ρ_d·E(uv) from the maps (ρ_d: the models' diffuse BRDF value, k_d/π) and the lights
#: add only the rest of f_r.
LIGHTMAP = (
    Param("directory", "str", doc="folder of the maps (object_000.exr, ... by object index), relative to the scene "
          "file; the bake writes it, the renderers read it"),
    Param("size", "int", 64, "texels per side of each object's map (in its UV chart, uv / uv_repeat)",
          bounds=(2, 4096)),
    Param("bounces", "int", 1, "diffuse bounces after the direct light (0: direct only)", bounds=(0, 16)),
    Param("samples", "int", 64, "hemisphere rays per texel (environment and bounces) and points per area light",
          bounds=(1, 1 << 16)),
    Param("seed", "int", 0, "seed of the bake's sample points", bounds=(0, None)),
    Param("smooth", "int", 1, "3x3 tent-filter passes over each bounce's map (indirect light is smooth; each pass "
          "cuts its Monte Carlo noise); 0: none", bounds=(0, 16)),
    Param("area_lights", "list", [], "rectangular emitters that light the bake only (diffuse): "
          "{position, size, rotate_deg, radiance}; they face +z after rotate_deg"),
    Param("use", "bool", True, "renderers shade diffuse from the maps (false: from the lights, as without a bake)"),
)

#: One ``lightmap: {area_lights: [...]}`` entry.
AREA_LIGHT = (
    Param("position", "list", doc="centre of the rectangle", length=3, item="float"),
    Param("size", "list", [1.0, 1.0], "extent along its own x and y", length=2, item="float", bounds=(1e-9, None)),
    Param("rotate_deg", "list", [180.0, 0.0, 0.0], "rotation about x, y, z; the default faces down (-z)", length=3,
          item="float", unit="deg"),
    Param("radiance", "any", 1.0, "emitted radiance L_e (a number or an RGB triple), one-sided"),
)

#: ``camera_path:``: a walkthrough (Mühlbacher §4.6.4): keyframes interpolated in time, rendered at ``fps``.
CAMERA_PATH = (
    Param("keyframes", "list", doc="at least two {time, position, look_at, fov_deg (optional)}, times increasing; "
          "two consecutive equal poses hold the camera still (progressive refinement there)"),
    Param("fps", "float", 24.0, "frames per second of the sequence", bounds=(0.1, 240.0)),
    Param("interpolation", "str", "catmull-rom", "between keyframes: linear, or catmull-rom (C1 through the keys)",
          choices=("linear", "catmull-rom")),
)

#: One ``camera_path: {keyframes: [...]}`` entry.
KEYFRAME = (
    Param("time", "float", doc="seconds from the start of the path", bounds=(0.0, None), unit="s"),
    Param("position", "list", doc="eye position", length=3, item="float"),
    Param("look_at", "list", doc="point at the centre of the image", length=3, item="float"),
    Param("fov_deg", "float", None, "vertical field of view; default: the camera's", nullable=True,
          bounds=(1.0, 170.0), unit="deg"),
)

#: The renderers' own top-level keys; plugins' sections (``environment``) come after them.
TOP_KEYS = ("camera", "materials", "objects", "lights", "shadows", "display", "background", "effects", "antialias",
            "lightmap", "camera_path")

#: Samples per pixel when a scene does not say (``antialias:``): a 2×2 stratified pattern.
ANTIALIAS_DEFAULT = 4
#: Most samples per pixel a scene may ask for (16×16 would be 256: the cpu renderer's memory grows with it).
ANTIALIAS_MAX = 64


class SceneError(SbrdfError):
    """A scene file failed validation; ``problems`` lists every problem with its line."""

    def __init__(self, problems: list[Problem]):
        self.problems = list(problems)
        super().__init__("scene is invalid:\n" + "\n".join(f"  {p}" for p in self.problems))


def downsample(image: np.ndarray, n: int) -> np.ndarray:
    """The box average of n×n pixel blocks of ``(H·n, W·n, C)`` ``image`` (linear radiance), in its dtype.

    Blocks are summed in float64, so a float32 image averages without its rounding growing with n².
    """
    if n == 1:
        return image
    Hn, Wn = image.shape[:2]
    blocks = image.reshape(Hn // n, n, Wn // n, n, *image.shape[2:]).astype(np.float64)
    return blocks.mean(axis=(1, 3)).astype(image.dtype, copy=False)


def rgb(value: Any) -> np.ndarray:
    """A number or an RGB triple as a float ``(3,)`` array."""
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    return np.repeat(v, 3) if v.size == 1 else v


@dataclass(frozen=True)
class Camera:
    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray
    fov_deg: float
    resolution: tuple[int, int]  # (width, height)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Right, up and forward unit vectors of the view."""
        forward = self.look_at - self.position
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        right = right / np.linalg.norm(right)
        return right, np.cross(right, forward), forward

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit ray directions through every pixel centre, ``(H, W, 3)``, row 0 at the top; and the origin."""
        W, H = self.resolution
        right, up, forward = self.basis()
        half = np.tan(np.radians(self.fov_deg) / 2)
        x = ((np.arange(W) + 0.5) / W * 2 - 1) * half * W / H
        y = (1 - (np.arange(H) + 0.5) / H * 2) * half
        d = forward + x[None, :, None] * right + y[:, None, None] * up
        return d / np.linalg.norm(d, axis=-1, keepdims=True), self.position

    def matrices(self, near: float, far: float) -> tuple[np.ndarray, np.ndarray]:
        """OpenGL view and projection matrices (row-major numpy; transpose for GLSL)."""
        right, up, forward = self.basis()
        view = np.eye(4)
        view[0, :3], view[1, :3], view[2, :3] = right, up, -forward
        view[:3, 3] = -view[:3, :3] @ self.position
        W, H = self.resolution
        f = 1 / np.tan(np.radians(self.fov_deg) / 2)
        proj = np.zeros((4, 4))
        proj[0, 0], proj[1, 1] = f * H / W, f
        proj[2, 2], proj[2, 3] = (far + near) / (near - far), 2 * far * near / (near - far)
        proj[3, 2] = -1
        return view, proj


@dataclass(frozen=True)
class SceneObject:
    shape: str
    material: str
    matrix: np.ndarray  # 4x4 object -> world
    uv_repeat: tuple[float, float]
    params: dict  # shape-specific (size, radius, height, segments, file)
    line: int | None = None


@dataclass(frozen=True)
class Light:
    type: str  # point | directional
    vector: np.ndarray  # position (point) or unit direction towards the light (directional)
    power: np.ndarray  # RGB intensity (point) or irradiance (directional)
    falloff: bool = True


@dataclass(frozen=True)
class MaterialRef:
    name: str
    artifact: str | None  # "input", a store path, or None for a uniform material
    model: str | None
    model_params: dict
    params: dict
    filter: str
    #: A material looked up in a store of a renderable artifact kind (a shading map), from a plugin's material
    #: keys: ``{"key": its store key, "store": "input" or a path, "options": the plugin's other keys}``.
    surface: dict | None = None


@dataclass(frozen=True)
class Features:
    """What a scene calls for; renderers compile and run exactly this.

    ``anisotropic`` is per material; the rest is scene-wide.
    """

    point_lights: int
    directional_lights: int
    falloff: str  # of the point lights: "all", "none" or "mixed"
    shadows: bool
    sections: tuple[str, ...]  # the plugin sections the scene gives (environment)
    anisotropic: dict[str, bool] = field(default_factory=dict)
    alpha: dict[str, bool] = field(default_factory=dict)
    two_sided: dict[str, bool] = field(default_factory=dict)  # transmissive models lit from either side
    lightmap: bool = False  # diffuse from the light maps; the lights add f_r − ρ_d

    @property
    def lights(self) -> int:
        return self.point_lights + self.directional_lights


@dataclass(frozen=True)
class Scene:
    file: str
    camera: Camera
    objects: tuple[SceneObject, ...]
    materials: dict[str, MaterialRef]
    lights: tuple[Light, ...]
    #: Plugins' top-level sections (``sbrdf_scene_keys``): name -> its resolved keys as attributes, or None.
    sections: dict[str, Any] = field(default_factory=dict)
    shadows: bool = False
    exposure: float | None = None
    gamma: str = "srgb"
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    effects: dict[str, dict] = field(default_factory=dict)  # scene-effect name -> options, for plugins' effects
    antialias: int = ANTIALIAS_DEFAULT  # samples per pixel, a square n²: an n×n stratified sub-pixel grid
    #: ``lightmap:`` values as attributes (``area_lights``: dicts with ``matrix`` and RGB ``radiance``), or None.
    lightmap: Any = None
    #: ``camera_path:`` values as attributes (``keyframes``: dicts with float times and array poses), or None.
    camera_path: Any = None

    @property
    def lightmapped(self) -> bool:
        """Whether renderers shade diffuse from the baked maps (``lightmap:`` given with ``use: true``)."""
        return self.lightmap is not None and bool(self.lightmap.use)

    def section(self, name: str) -> Any:
        """A plugin section's values (attributes named as its keys), or None when the scene does not give it."""
        return self.sections.get(name)

    @property
    def subpixels(self) -> int:
        """n of the n×n stratified sub-pixel grid (``antialias`` = n²)."""
        return int(round(self.antialias ** 0.5))

    def supersampled(self) -> Scene:
        """The scene its antialiased render rasterises: the resolution × n in each direction, antialias 1.

        Pixel (i, j) of this scene's image is sub-sample (i mod n, j mod n) of pixel (i // n, j // n) of
        the scene's: the stratified n×n pattern with sub-sample centres at ((a + ½)/n, (b + ½)/n) inside
        every pixel.  Both renderers draw it and average n×n blocks in linear radiance
        (:func:`downsample`), so ``cpu`` and ``gl`` sample the same points.
        """
        n = self.subpixels
        if n == 1:
            return self
        W, H = self.camera.resolution
        return dataclasses.replace(self, camera=dataclasses.replace(self.camera, resolution=(W * n, H * n)),
                                   antialias=1)

    def features(self, materials: dict[str, Any] | None = None) -> Features:
        """The effects this scene needs; ``materials`` (name -> resolved material) adds per-material flags."""
        used = {o.material for o in self.objects}
        materials = materials or {}
        falloff = {lt.falloff for lt in self.lights if lt.type == "point"}
        return Features(
            point_lights=sum(lt.type == "point" for lt in self.lights),
            directional_lights=sum(lt.type == "directional" for lt in self.lights),
            falloff="mixed" if len(falloff) == 2 else ("none" if falloff == {False} else "all"),
            shadows=self.shadows,
            sections=tuple(k for k, v in self.sections.items() if v is not None),
            anisotropic={m: bool(optional(materials[m].model, "anisotropic", "brdf-model")) for m in used if m in materials},
            alpha={m: materials[m].alpha is not None for m in used if m in materials},
            two_sided={m: bool(optional(materials[m].model, "two_sided", "brdf-model")) for m in used if m in materials},
            lightmap=self.lightmapped,
        )

    def bounds(self) -> tuple[np.ndarray, float]:
        """A bounding sphere (centre, radius) of all objects, for clip planes and shadow maps."""
        pts = []
        for o in self.objects:
            r = {"plane": 0.5 * float(np.hypot(*o.params.get("size", (1, 1)))),
                 "sphere": o.params.get("radius", 1.0),
                 "cylinder": float(np.hypot(o.params.get("radius", 1.0), o.params.get("height", 1.0) / 2))}.get(o.shape)
            scale = np.cbrt(abs(np.linalg.det(o.matrix[:3, :3])))
            centre = o.matrix[:3, 3]
            if r is None:  # a mesh: the farthest of its vertices from its own origin
                r = mesh_vertex_radius(str(o.params["file"]))
            pts.append((centre, r * scale))
        if not pts:
            return np.zeros(3), 1.0
        centre = np.mean([c for c, _ in pts], axis=0)
        return centre, float(max(np.linalg.norm(c - centre) + r for c, r in pts))


def transform_matrix(translate, rotate_deg, scale) -> np.ndarray:
    """4x4 object-to-world matrix: scale, then rotate about x, y, z, then translate."""
    ax, ay, az = np.radians(rotate_deg)
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = rz @ ry @ rx * scale
    m[:3, 3] = translate
    return m


@dataclass(frozen=True)
class PluginKeys:
    """The scene keys installed plugins add (``sbrdf_scene_keys``), merged."""

    #: Top-level sections: name -> a ``dict`` Param whose ``schema`` declares the section's keys.
    sections: dict[str, Param] = field(default_factory=dict)
    #: Groups of material keys; a group's ``extra={"store": True}`` key names the store, the rest are its options.
    material: tuple[tuple[Param, ...], ...] = ()
    #: Keys of every object, and of one shape's objects.
    objects: tuple[Param, ...] = ()
    shapes: dict[str, tuple[Param, ...]] = field(default_factory=dict)

    @property
    def material_params(self) -> tuple[Param, ...]:
        return tuple(p for group in self.material for p in group)


def plugin_keys(registry=None) -> PluginKeys:
    """The scene keys every installed plugin declares through ``sbrdf_scene_keys``.

    Each implementation returns ``{scope: (Param, ...)}`` with scopes ``scene`` (sections),
    ``material``, ``object`` and ``object.<shape>``.
    """
    from sbrdf_core.registry import default_registry

    registry = registry if registry is not None else default_registry()
    hook = getattr(registry.pm.hook, "sbrdf_scene_keys", None)
    sections: dict[str, Param] = {}
    material: list[tuple[Param, ...]] = []
    objects: list[Param] = []
    shapes: dict[str, tuple[Param, ...]] = {}
    for declared in (hook() if hook is not None else []):
        for scope, params in (declared or {}).items():
            params = tuple(params)
            if scope == "scene":
                for p in params:
                    if p.name in TOP_KEYS or p.name in sections:
                        raise SbrdfError(f"scene key {p.name!r} is declared twice (sbrdf_scene_keys)")
                    sections[p.name] = p
            elif scope == "material":
                material.append(params)
            elif scope == "object":
                objects.extend(params)
            elif scope.startswith("object."):
                shapes[scope[len("object."):]] = shapes.get(scope[len("object."):], ()) + params
            else:
                raise SbrdfError(f"sbrdf_scene_keys: unknown scope {scope!r}; use scene, material, object or "
                                 "object.<shape>")
    return PluginKeys(sections, tuple(material), tuple(objects), shapes)


def _unreadable(path: str, text: bool) -> str | None:
    """Why a file a scene names cannot be read (``does not exist``, a device, over the size limit), or ``None``."""
    try:
        input_files.check_file(path, text=text)
    except FileNotFoundError:
        return "does not exist"
    except OSError as e:
        return f"cannot be read: {e.strerror}"
    return None


def load_scene(source: str | Path, material_names: tuple[str, ...] = (), registry=None) -> Scene:
    """Read and validate a scene file; raises :class:`SceneError` listing every problem with its line.

    ``source`` is a path, or YAML text (containing a newline) whose relative paths resolve from the cwd.
    The keys plugins add come from ``registry`` (default: the installed plugins).
    """
    src = str(source)
    if "\n" in src:
        text, file, base = src, "<scene>", Path.cwd()
    else:
        try:
            text = _yaml.read_text(src)
        except OSError as e:
            raise SceneError([Problem(f"cannot read scene file: {e.strerror}", src)]) from None
        except yaml.YAMLError as e:
            raise SceneError([_yaml.syntax_problem(e, src)]) from None
        file, base = src, Path(src).resolve().parent
    return _SceneValidator(text, file, base, plugin_keys(registry), registry).run()


class _SceneValidator:
    def __init__(self, text: str, file: str, base: Path, keys: PluginKeys, registry=None):
        self.text, self.file, self.base, self.keys, self.registry = text, file, base, keys, registry
        self.problems: list[Problem] = []

    def problem(self, message: str, path: tuple = ()) -> None:
        self.problems.append(Problem(message, self.file, self.loc.line(path)))

    def params(self, declared, given, owner: str, path: tuple) -> dict:
        if not isinstance(given, dict):
            self.problem(f"{owner} must be a mapping", path)
            given = {}
        values, problems = resolve(declared, given, owner)
        for key, msg in problems:
            self.problem(msg, path + (key,) if key is not None else path)
        return values

    def path(self, value: str) -> str:
        return _yaml.relative_to(self.base, value)

    def run(self) -> Scene:
        try:
            doc, self.loc = _yaml.load(self.text)
        except yaml.YAMLError as e:
            raise SceneError([_yaml.syntax_problem(e, self.file)]) from None
        if not isinstance(doc, dict):
            raise SceneError([Problem("a scene must be a mapping with 'camera', 'objects' and 'lights'", self.file, 1)])
        for path, line in self.loc.duplicates:
            self.problems.append(Problem(f"duplicate key {path[-1]!r}", self.file, line))
        allowed = TOP_KEYS + tuple(self.keys.sections)
        for key in doc:
            if key not in allowed:
                self.problem(f"unknown scene key {key!r}; allowed: {', '.join(allowed)}", (key,))
        cam = self.params(CAMERA, doc.get("camera", {}), "camera", ("camera",))
        camera = None
        if len(cam) == len(CAMERA):
            camera = Camera(np.array(cam["position"]), np.array(cam["look_at"]), np.array(cam["up"]),
                            cam["fov_deg"], tuple(cam["resolution"]))
            fwd = camera.look_at - camera.position
            if np.linalg.norm(fwd) < 1e-12 or np.linalg.norm(np.cross(fwd, camera.up)) < 1e-9 * np.linalg.norm(fwd):
                self.problem("camera: look_at must differ from position and not lie along up", ("camera",))
        materials = self.materials(doc.get("materials", {"sample": {"artifact": "input"}}))
        objects = self.objects(doc.get("objects"), materials)
        lights = self.lights(doc.get("lights", []))
        sections = {name: self.section(name, p, doc.get(name)) for name, p in self.keys.sections.items()}
        shadows = doc.get("shadows", False)
        if not isinstance(shadows, bool):
            self.problem(f"shadows must be true or false, got {shadows!r}", ("shadows",))
        display = self.params(DISPLAY, doc.get("display", {}), "display", ("display",))
        background = doc.get("background", [0.0, 0.0, 0.0])
        try:
            background = rgb(background)
            assert background.shape == (3,) and np.all(np.isfinite(background))
        except (ValueError, TypeError, AssertionError):
            self.problem(f"background must be a number or an RGB triple, got {doc.get('background')!r}", ("background",))
            background = np.zeros(3)
        antialias = doc.get("antialias", ANTIALIAS_DEFAULT)
        if (not isinstance(antialias, int) or isinstance(antialias, bool) or not 1 <= antialias <= ANTIALIAS_MAX
                or round(antialias ** 0.5) ** 2 != antialias):
            squares = ", ".join(str(k * k) for k in range(1, int(ANTIALIAS_MAX ** 0.5) + 1))
            self.problem(f"antialias must be a number of samples per pixel that is a square (an n×n sub-pixel "
                         f"grid): one of {squares} (1: off), got {doc.get('antialias')!r}", ("antialias",))
            antialias = 1
        effects = doc.get("effects") or {}
        if not isinstance(effects, dict) or not all(isinstance(v, (dict, type(None))) for v in effects.values()):
            self.problem(f"effects must map scene-effect names to their options, e.g. {{ambient: {{radiance: 0.1}}}}, "
                         f"got {doc.get('effects')!r}", ("effects",))
            effects = {}
        lightmap = self.lightmap(doc.get("lightmap"))
        for o in objects:  # a mesh without UVs gets a chart where a light map needs one
            if o.shape == "mesh" and o.params.get("uv_layout") == "auto":
                o.params["uv_layout"] = "chart" if lightmap is not None else "planar"
        camera_path = self.camera_path(doc.get("camera_path"), camera)
        lit = [n for n, p in self.keys.sections.items() if (p.extra or {}).get("light")]
        if not lights and not any(sections[n] is not None for n in lit) and not (lightmap and lightmap.area_lights):
            self.problem(f"the scene has no light: add {' or '.join(['lights:'] + [n + ':' for n in lit])}", ())
        if self.problems:
            raise SceneError(sorted(self.problems, key=lambda p: (p.line or 0, p.message)))
        assert camera is not None, "a camera section that did not resolve is a problem, raised above"
        return Scene(self.file, camera, tuple(objects), materials, tuple(lights), sections, shadows,
                     display["exposure"], display["gamma"], background, {str(k): dict(v or {}) for k, v in effects.items()},
                     antialias, lightmap=lightmap, camera_path=camera_path)

    def camera_path(self, raw, camera) -> Any:
        """The ``camera_path:`` section, keyframes checked (times increasing, valid views), or None."""
        if raw is None:
            return None
        values = self.params(CAMERA_PATH, raw, "camera_path", ("camera_path",))
        if len(values) < len(CAMERA_PATH):
            return None
        keys: list[dict[str, Any]] = []
        raw_keys = values["keyframes"] if isinstance(values["keyframes"], list) else []
        if len(raw_keys) < 2:
            self.problem("camera_path: keyframes must be a list of at least two {time, position, look_at}",
                         ("camera_path", "keyframes"))
        for i, decl in enumerate(raw_keys):
            path = ("camera_path", "keyframes", i)
            k = self.params(KEYFRAME, decl, f"camera_path keyframe {i}", path)
            if len(k) < len(KEYFRAME):
                continue
            pos, look = np.array(k["position"]), np.array(k["look_at"])
            up = camera.up if camera is not None else np.array([0.0, 0.0, 1.0])
            fwd = look - pos
            if np.linalg.norm(fwd) < 1e-12 or np.linalg.norm(np.cross(fwd, up)) < 1e-9 * np.linalg.norm(fwd):
                self.problem(f"camera_path keyframe {i}: look_at must differ from position and not lie along up", path)
            if keys and k["time"] <= keys[-1]["time"]:
                self.problem(f"camera_path keyframe {i}: time {k['time']} must be after the previous keyframe's "
                             f"({keys[-1]['time']})", path + ("time",))
            keys.append({"time": k["time"], "position": pos, "look_at": look, "fov_deg": k["fov_deg"]})
        values["keyframes"] = keys
        return SimpleNamespace(**values)

    def lightmap(self, raw) -> Any:
        """The ``lightmap:`` section (directory resolved from the scene file; it need not exist yet), or None."""
        if raw is None:
            return None
        values = self.params(LIGHTMAP, raw, "lightmap", ("lightmap",))
        if len(values) < len(LIGHTMAP):
            return None
        values["directory"] = self.path(values["directory"])
        areas = []
        for i, decl in enumerate(values["area_lights"] or []):
            path = ("lightmap", "area_lights", i)
            a = self.params(AREA_LIGHT, decl, f"lightmap area light {i}", path)
            if len(a) < len(AREA_LIGHT):
                continue
            try:
                radiance = rgb(a["radiance"])
                assert radiance.shape == (3,) and np.all(np.isfinite(radiance)) and np.all(radiance >= 0)
            except (ValueError, TypeError, AssertionError):
                self.problem(f"lightmap area light {i}: radiance must be a non-negative number or RGB triple, got "
                             f"{a['radiance']!r}", path + ("radiance",))
                continue
            areas.append({"matrix": transform_matrix(a["position"], a["rotate_deg"], 1.0), "size": tuple(a["size"]),
                          "radiance": radiance})
        values["area_lights"] = areas
        return SimpleNamespace(**values)

    def section(self, name: str, declared: Param, raw) -> Any:
        """A plugin section's values (paths resolved from the scene file and checked), or None when absent."""
        if raw is None:
            return None
        schema = declared.schema or ()
        values = self.params(schema, raw, name, (name,))
        if len(values) < len(schema):  # a bad key is reported; the section is not built
            return None
        for p in schema:
            if (p.extra or {}).get("path") and isinstance(values[p.name], str):
                values[p.name] = self.path(values[p.name])
                if "://" not in values[p.name]:
                    why = _unreadable(values[p.name], text=False)
                    if why:
                        self.problem(f"{name}: {p.name} {values[p.name]} {why}", (name, p.name))
        return SimpleNamespace(**values)

    def materials(self, raw) -> dict[str, MaterialRef]:
        out: dict[str, MaterialRef] = {}
        if not isinstance(raw, dict):
            self.problem("materials must be a mapping of name -> {artifact} or {model, params}", ("materials",))
            return out
        for name, decl in raw.items():
            path = ("materials", name)
            m = self.params(MATERIAL + self.keys.material_params, decl, f"material {name!r}", path)
            if not m:
                continue
            art, model = m["artifact"], m["model"]
            if (art is None) == (model is None):
                self.problem(f"material {name!r}: give either artifact: (input or a store path) or model: with params:", path)
                continue
            if art is not None and art != "input":
                art = self.path(art)
            surface = None
            for group in self.keys.material:
                for p in group:
                    if (p.extra or {}).get("store") and m.get(p.name) is not None:
                        store = m[p.name] if m[p.name] == "input" else self.path(m[p.name])
                        surface = {"key": p.name, "store": store,
                                   "options": {q.name: m[q.name] for q in group if q is not p and q.name in m}}
            out[str(name)] = MaterialRef(str(name), art, model, self.model_paths(model, m["model_params"]), m["params"],
                                         m.get("filter", "bilinear"), surface)
        return out

    def model_paths(self, model, model_params: dict) -> dict:
        """A model's file parameters (declared ``extra={"path": True}``, e.g. merl's ``path``) are relative to the
        scene file, as a graph's are to the graph file; an unknown model is reported where it is created."""
        if model is None or not model_params:
            return model_params
        from sbrdf_core.errors import PluginError
        from sbrdf_core.registry import default_registry

        try:
            declared = (self.registry or default_registry()).get("brdf-model", model).params or ()
        except PluginError:
            return model_params
        out = dict(model_params)
        for p in declared:
            if (p.extra or {}).get("path") and isinstance(out.get(p.name), str):
                out[p.name] = self.path(out[p.name])
        return out

    def objects(self, raw, materials) -> list[SceneObject]:
        if not isinstance(raw, list) or not raw:
            self.problem("objects must be a non-empty list of {shape, ...}", ("objects",))
            return []
        out = []
        for i, decl in enumerate(raw):
            path = ("objects", i)
            shape = decl.get("shape") if isinstance(decl, dict) else None
            if shape not in SHAPES:
                self.problem(f"object {i}: shape {shape!r} is not one of {list(SHAPES)}", path + ("shape",))
                continue
            o = self.params(OBJECT + SHAPES[shape] + self.keys.shapes.get(shape, ()) + self.keys.objects, decl,
                            f"object {i} ({shape})", path)
            if "material" not in o:
                continue
            if o["material"] not in materials:
                self.problem(f"object {i}: unknown material {o['material']!r}; defined: {sorted(materials)}",
                             path + ("material",))
            t = self.params(TRANSFORM, o["transform"], f"object {i} transform", path + ("transform",))
            if len(t) < len(TRANSFORM):
                continue
            params = {k: o[k] for k in o if k not in {p.name for p in OBJECT}}
            if shape == "mesh" and "file" in params:
                params["file"] = self.path(params["file"])
                suffix = Path(params["file"]).suffix.lower()
                if suffix not in MESH_FORMATS:
                    self.problem(f"object {i}: mesh file {params['file']}: unsupported format "
                                 f"{suffix or '(no suffix)'!r}; supported: {', '.join(MESH_FORMATS)}", path + ("file",))
                elif "://" not in params["file"] and (why := _unreadable(params["file"], text=False)):
                    self.problem(f"object {i}: mesh file {params['file']} {why}", path + ("file",))
                elif "://" not in params["file"] and suffix != ".obj":  # OBJ errors: the renderers' check_scene
                    try:
                        load_mesh(params["file"])
                    except (SbrdfError, ImportError) as e:
                        self.problem(f"object {i}: mesh: {e}", path + ("file",))
            out.append(SceneObject(shape, o["material"], transform_matrix(t["translate"], t["rotate_deg"], t["scale"]),
                                   tuple(o["uv_repeat"]), params, self.loc.line(path)))
        return out

    def lights(self, raw) -> list[Light]:
        if not isinstance(raw, list):
            self.problem("lights must be a list of {type: point|directional, ...}", ("lights",))
            return []
        out = []
        for i, decl in enumerate(raw):
            path = ("lights", i)
            kind = decl.get("type") if isinstance(decl, dict) else None
            if kind not in LIGHTS:
                self.problem(f"light {i}: type {kind!r} is not one of {list(LIGHTS)}", path + ("type",))
                continue
            lt = self.params(LIGHTS[kind] + (Param("type", "str"),), decl, f"light {i} ({kind})", path)
            key = "intensity" if kind == "point" else "irradiance"
            try:
                power = rgb(lt.get(key, 1.0))
                assert power.shape == (3,) and np.all(np.isfinite(power)) and np.all(power >= 0)
            except (ValueError, TypeError, AssertionError):
                self.problem(f"light {i}: {key} must be a non-negative number or RGB triple, got {lt.get(key)!r}",
                             path + (key,))
                continue
            if kind == "point" and "position" in lt:
                out.append(Light("point", np.array(lt["position"]), power, lt["falloff"]))
            elif kind == "directional" and "direction" in lt:
                d = np.array(lt["direction"])
                if np.linalg.norm(d) < 1e-12:
                    self.problem(f"light {i}: direction must not be zero", path + ("direction",))
                    continue
                out.append(Light("directional", d / np.linalg.norm(d), power, False))
        return out


def scene_fingerprint(path: str, registry=None) -> str:
    """Cache-key material for renderers: the scene's text and the size and time of every file it names.

    A changed scene, mesh, environment map or referenced material store re-renders; an unchanged one is cached.
    """
    import hashlib
    import os

    h = hashlib.sha256()
    try:
        h.update(input_files.read_bytes(path, text=True))  # regular files only, bounded (as load_scene reads it)
        keys = plugin_keys(registry)
        scene = load_scene(path, registry=registry)
    except (OSError, SceneError):
        return h.hexdigest()  # validation reports the problem
    files = [f for o in scene.objects if o.shape == "mesh" for f in mesh_files(o.params["file"])]
    for name, p in keys.sections.items():
        value = scene.section(name)
        files += [getattr(value, q.name) for q in (p.schema or ()) if value is not None and (q.extra or {}).get("path")]
    files += [str(Path(m.artifact) / "zarr.json") for m in scene.materials.values() if m.artifact not in (None, "input")]
    files += [str(Path(m.surface["store"]) / "zarr.json") for m in scene.materials.values()
              if m.surface and m.surface["store"] != "input"]
    if scene.lightmap is not None:  # a re-bake re-renders
        from .lightmap import map_path

        files += [map_path(scene.lightmap.directory, k) for k in range(len(scene.objects))]
    for f in files:
        try:
            st = os.stat(f)
            h.update(f"{f}:{st.st_size}:{st.st_mtime_ns}".encode())
        except OSError:
            h.update(f"{f}:missing".encode())
    return h.hexdigest()


def param_table(params) -> str:
    """A Markdown table of declarations (the reference pages' format)."""
    from sbrdf_core.docgen import param_table as table

    return table(params)


def reference(registry=None) -> str:
    """The scene-file reference page (Markdown): every key, the renderers' and the installed plugins'."""
    keys = plugin_keys(registry)
    out = ["# Scene-file reference", "",
           "Generated from `sbrdf_lib/scene.py` and the plugins' `sbrdf_scene_keys`; see "
           "[scenes and renderers](../scenes.md) for conventions.", "",
           "## `camera`", "", param_table(CAMERA),
           "## `materials: {name: ...}`", "", param_table(MATERIAL + keys.material_params),
           "## `objects: [...]`", "", "Every object:", "", param_table(OBJECT + keys.objects)]
    for shape, params in SHAPES.items():
        out += [f"`shape: {shape}`:", "", param_table(params + keys.shapes.get(shape, ()))]
    out += ["### `transform`", "", param_table(TRANSFORM), "## `lights: [...]`", ""]
    for kind, params in LIGHTS.items():
        out += [f"`type: {kind}`:", "", param_table(params)]
    for name, p in keys.sections.items():
        out += [f"## `{name}`", "", p.doc, "", param_table(p.schema or ())]
    out += ["## `camera_path`", "", "A walkthrough (docs/walkthrough.md).", "", param_table(CAMERA_PATH),
            "`keyframes: [...]`:", "", param_table(KEYFRAME)]
    out += ["## `lightmap`", "", "Per-object irradiance maps (docs/walkthrough.md), baked by the `LightmapBake` node.",
            "", param_table(LIGHTMAP), "`area_lights: [...]`:", "", param_table(AREA_LIGHT)]
    out += ["## `display`", "", param_table(DISPLAY),
            "## Other keys", "", "`shadows` (bool, default false), `background` (a number or an RGB triple), "
            "`effects` (scene-effect name -> its options, for effects that plugins add, e.g. "
            "`{ambient: {radiance: 0.1}}`).", ""]
    return "\n".join(out) + "\n"
