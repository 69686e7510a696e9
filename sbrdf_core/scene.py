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

Every key is declared once below as :class:`~sbrdf_core.params.Param` data,
so an unknown key, a wrong type or a missing value is reported with the
scene file's line, like graphs.  Renderers read :func:`Scene.features` to
decide which effects (and which shader code) the scene needs.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from . import _yaml
from .errors import Problem, SbrdfError
from .params import Param, resolve

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

_OBJECT_COMMON = (
    Param("shape", "str", choices=("plane", "sphere", "cylinder", "mesh"), doc="geometry"),
    Param("material", "str", "sample", "name of an entry of materials:"),
    Param("transform", "dict", {}, "placement: translate, rotate_deg, scale"),
    Param("uv_repeat", "list", [1.0, 1.0], "texture repeats across the surface in u and v", length=2, item="float",
          bounds=(1e-6, None)),
)

#: Shape-specific keys.  Built-in shapes are centred at the origin with +z up.
SHAPES = {
    "plane": (Param("size", "list", [1.0, 1.0], "extent in x and y (u runs along +x, v along +y)", length=2, item="float",
                    bounds=(1e-9, None)),
              Param("reflector", "bool", False, "a planar reflector: its specular lobes reflect the other objects "
                    "(the mirror scene effect, docs/environment-lighting.md)")),
    "sphere": (Param("radius", "float", 0.5, "radius", bounds=(1e-9, None)),
               Param("segments", "list", [128, 64], "GL tessellation in longitude and latitude", length=2, item="int",
                     bounds=(3, 4096))),
    "cylinder": (Param("radius", "float", 0.5, "radius", bounds=(1e-9, None)),
                 Param("height", "float", 1.0, "extent along z (no caps)", bounds=(1e-9, None)),
                 Param("segments", "int", 128, "GL tessellation around the axis", bounds=(3, 4096))),
    "mesh": (Param("file", "str", doc="triangle mesh (OBJ), relative to the scene file"),),
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
    Param("shading_map", "str", None, "'input' (the Render node's input) or a ShadingMap or PowerShadingMap store "
          "(relative to the scene file), looked up with model: and params: (Kautz et al. 2003, docs/shading-maps.md)",
          nullable=True),
    Param("variant", "str", "r", "shading-map lookup (Fig 6): by r, by outgoing radiance, by angle, or a slice as "
          "texture", choices=("r", "radiance", "angle", "texture")),
    Param("above_max", "str", "clamp", "shading-map lookups above a_max: clamp to, or scale, the brightest slice",
          choices=("clamp", "scale")),
    Param("sigma", "float", 1.0, "σ of Eq 2: the shading-mapped material's shade", bounds=(0.0, None)),
)

LIGHTS = {
    "point": (Param("position", "list", doc="light position", length=3, item="float"),
              Param("intensity", "any", 1.0, "radiant intensity I (a number or an RGB triple)"),
              Param("falloff", "bool", True, "inverse-square fall-off: E = I cos θ / d²; false: E = I cos θ")),
    "directional": (Param("direction", "list", doc="direction towards the light", length=3, item="float"),
                    Param("irradiance", "any", 1.0, "irradiance at normal incidence (a number or an RGB triple)")),
}

ENVIRONMENT = (
    Param("file", "str", doc="EXR environment map, relative to the scene file"),
    Param("layout", "str", "latlong", "map layout", choices=("latlong", "cube")),
    Param("intensity", "float", 1.0, "radiance scale", bounds=(0.0, None)),
    Param("options", "dict", {}, "options of the environment scene effect (docs/environment-lighting.md)"),
)

DISPLAY = (
    Param("exposure", "float", None, "linear scale before display; default maps the 99th percentile to 0.8",
          nullable=True, bounds=(0.0, None)),
    Param("gamma", "str", "srgb", "display transfer of the PNG", choices=("srgb", "2.2")),
)

TOP_KEYS = ("camera", "materials", "objects", "lights", "environment", "shadows", "display", "background", "effects",
            "antialias")

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
    shading: dict | None = None  # {store, variant, above_max, sigma} for a shading-mapped material


@dataclass(frozen=True)
class Environment:
    file: str
    layout: str
    intensity: float
    options: dict = field(default_factory=dict)  # for the environment scene effect, validated by it


@dataclass(frozen=True)
class Features:
    """What a scene calls for; renderers compile and run exactly this.

    ``anisotropic`` is per material; the rest is scene-wide.
    """

    point_lights: int
    directional_lights: int
    falloff: str  # of the point lights: "all", "none" or "mixed"
    shadows: bool
    environment: bool
    anisotropic: dict[str, bool] = field(default_factory=dict)
    alpha: dict[str, bool] = field(default_factory=dict)
    two_sided: dict[str, bool] = field(default_factory=dict)  # transmissive models lit from either side

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
    environment: Environment | None = None
    shadows: bool = False
    exposure: float | None = None
    gamma: str = "srgb"
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    effects: dict[str, dict] = field(default_factory=dict)  # scene-effect name -> options, for plugins' effects
    antialias: int = ANTIALIAS_DEFAULT  # samples per pixel, a square n²: an n×n stratified sub-pixel grid

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
            environment=self.environment is not None,
            anisotropic={m: bool(getattr(materials[m].model, "anisotropic", False)) for m in used if m in materials},
            alpha={m: materials[m].alpha is not None for m in used if m in materials},
            two_sided={m: bool(getattr(materials[m].model, "two_sided", False)) for m in used if m in materials},
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
                r = obj_vertex_radius(str(o.params["file"]))
            pts.append((centre, r * scale))
        if not pts:
            return np.zeros(3), 1.0
        centre = np.mean([c for c, _ in pts], axis=0)
        return centre, float(max(np.linalg.norm(c - centre) + r for c, r in pts))


@functools.lru_cache(maxsize=64)
def obj_vertex_radius(path: str) -> float:
    """Largest distance of an OBJ file's ``v`` vertices from its origin: a mesh's bounding sphere.

    Only the vertex lines are read (renderers parse the whole file with their own
    loader); an unreadable or vertex-less file gives 1, and the renderer that
    loads it reports the error with its line.
    """
    try:
        with open(path) as f:
            rows = [line.split()[1:4] for line in f if line.startswith("v ")]
        v = np.asarray(rows, dtype=float)
    except (OSError, ValueError):
        return 1.0
    return float(np.sqrt((v**2).sum(axis=1)).max()) if v.ndim == 2 and len(v) else 1.0


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


def load_scene(source: str | Path, material_names: tuple[str, ...] = ()) -> Scene:
    """Read and validate a scene file; raises :class:`SceneError` listing every problem with its line.

    ``source`` is a path, or YAML text (containing a newline) whose relative paths resolve from the cwd.
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
    return _SceneValidator(text, file, base).run()


class _SceneValidator:
    def __init__(self, text: str, file: str, base: Path):
        self.text, self.file, self.base = text, file, base
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
        for key in doc:
            if key not in TOP_KEYS:
                self.problem(f"unknown scene key {key!r}; allowed: {', '.join(TOP_KEYS)}", (key,))
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
        env = None
        if doc.get("environment") is not None:
            e = self.params(ENVIRONMENT, doc["environment"], "environment", ("environment",))
            if len(e) == len(ENVIRONMENT):  # every key valid (a bad one is reported; no KeyError)
                env = Environment(self.path(e["file"]), e["layout"], e["intensity"], e["options"])
                if "://" not in env.file and not Path(env.file).is_file():
                    self.problem(f"environment: file {env.file} does not exist", ("environment", "file"))
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
        if not lights and env is None:
            self.problem("the scene has no light: add lights: or environment:", ())
        if self.problems:
            raise SceneError(sorted(self.problems, key=lambda p: (p.line or 0, p.message)))
        return Scene(self.file, camera, tuple(objects), materials, tuple(lights), env, shadows,
                     display["exposure"], display["gamma"], background, {str(k): dict(v or {}) for k, v in effects.items()},
                     antialias)

    def materials(self, raw) -> dict[str, MaterialRef]:
        out = {}
        if not isinstance(raw, dict):
            self.problem("materials must be a mapping of name -> {artifact} or {model, params}", ("materials",))
            return out
        for name, decl in raw.items():
            path = ("materials", name)
            m = self.params(MATERIAL, decl, f"material {name!r}", path)
            if not m:
                continue
            art, model = m["artifact"], m["model"]
            if (art is None) == (model is None):
                self.problem(f"material {name!r}: give either artifact: (input or a store path) or model: with params:", path)
                continue
            if art is not None and art != "input":
                art = self.path(art)
            shading = None
            if m["shading_map"] is not None:
                store = m["shading_map"] if m["shading_map"] == "input" else self.path(m["shading_map"])
                shading = {"store": store, "variant": m["variant"], "above_max": m["above_max"],
                           "sigma": m["sigma"]}
            out[str(name)] = MaterialRef(str(name), art, model, m["model_params"], m["params"], m.get("filter", "bilinear"), shading)
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
            o = self.params(_OBJECT_COMMON + SHAPES[shape], decl, f"object {i} ({shape})", path)
            if "material" not in o:
                continue
            if o["material"] not in materials:
                self.problem(f"object {i}: unknown material {o['material']!r}; defined: {sorted(materials)}",
                             path + ("material",))
            t = self.params(TRANSFORM, o["transform"], f"object {i} transform", path + ("transform",))
            if len(t) < len(TRANSFORM):
                continue
            params = {k: o[k] for k in o if k not in {p.name for p in _OBJECT_COMMON}}
            if shape == "mesh" and "file" in params:
                params["file"] = self.path(params["file"])
                if "://" not in params["file"] and not Path(params["file"]).exists():
                    self.problem(f"object {i}: mesh file {params['file']} does not exist", path + ("file",))
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


def check_scene_param(params, registry=None) -> list[tuple[str, str]]:
    """``check_params`` for renderers taking a ``scene`` file: its problems, reported at graph load.

    Beyond the file itself (:func:`load_scene`): the scene effects it wants,
    constructed from their options and asked to ``check`` their files
    (:func:`effect_problems`), so a bad option or a missing environment map
    is an error before anything runs, not after the upstream nodes computed.
    """
    try:
        scene = load_scene(params["scene"])
    except SceneError as e:
        return [("scene", "; ".join(str(p) for p in e.problems))]
    return [("scene", msg) for msg in effect_problems(scene, registry)]


def effect_problems(scene: Scene, registry=None) -> list[str]:
    """What would stop a renderer constructing the scene's effects, found without rendering.

    Every installed scene effect the scene wants is constructed from its
    options (a constructor only stores and checks them); one that defines
    ``check(scene) -> [message]`` then checks what it will read (an
    environment map's file).  Effects named in ``effects:`` that no plugin
    provides, and ``environment:`` or ``reflector: true`` without their
    effect, are reported too.
    """
    from .registry import default_registry

    registry = registry if registry is not None else default_registry()
    out: list[str] = []
    provided: set[str] = set()
    for name in registry.names("scene-effect"):
        try:
            cls = registry.load(registry.get("scene-effect", name))
            if not cls.wanted(scene):
                continue
            provided.add(name)
            effect = registry.create("scene-effect", name, cls.options(scene))
            check = getattr(effect, "check", None)
            out += [f"{scene.file}: scene effect {name!r}: {m}" for m in (check(scene) if callable(check) else [])]
        except SbrdfError as e:
            msg = str(e)
            out.append(f"{scene.file}: " + (msg if msg.startswith("scene-effect ") else f"scene effect {name!r}: {msg}"))
    if scene.environment is not None and "environment" not in provided:
        out.append(f"{scene.file}: environment lighting needs the environment scene effect, which is not installed")
    if any(o.params.get("reflector") for o in scene.objects) and "mirror" not in provided:
        out.append(f"{scene.file}: reflector: true needs the mirror scene effect, which is not installed")
    missing = sorted(set(scene.effects) - provided)
    if missing:
        out.append(f"{scene.file}: effects: no installed scene effect provides {missing} "
                   "(see `sbrdf plugins --category scene-effect`)")
    return out


def scene_fingerprint(path: str) -> str:
    """Cache-key material for renderers: the scene's text and the size and time of every file it names.

    A changed scene, mesh, environment map or referenced material store re-renders; an unchanged one is cached.
    """
    import hashlib
    import os

    h = hashlib.sha256()
    try:
        h.update(Path(path).read_bytes())
        scene = load_scene(path)
    except (OSError, SceneError):
        return h.hexdigest()  # validation reports the problem
    files = [o.params["file"] for o in scene.objects if o.shape == "mesh"]
    files += [scene.environment.file] if scene.environment else []
    files += [str(Path(m.artifact) / "zarr.json") for m in scene.materials.values() if m.artifact not in (None, "input")]
    files += [str(Path(m.shading["store"]) / "zarr.json") for m in scene.materials.values()
              if m.shading and m.shading["store"] != "input"]
    for f in files:
        try:
            st = os.stat(f)
            h.update(f"{f}:{st.st_size}:{st.st_mtime_ns}".encode())
        except OSError:
            h.update(f"{f}:missing".encode())
    return h.hexdigest()
