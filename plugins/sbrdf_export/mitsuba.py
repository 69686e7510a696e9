"""mitsuba: a Mitsuba 3 scene of the material: EXR bitmaps, a BSDF Mitsuba has, and ``scene.xml``.

The material is refitted per texel to a GGX lobe with a specular weight
(:func:`sbrdf_lib.convert.to_ggx`: ρ_d, specular colour F0c, weight s, α ≤ 1)
and written as the sum f = ρ_d + s F D G / (4 cos θ_i cos θ_o), which Mitsuba
expresses as

    blendbsdf(weight 0.5,  diffuse(reflectance = 2 π ρ_d),
                           roughconductor(ggx, alpha = α, eta = η(F0c), k = 0, specular_reflectance = 2 s))

(a blend of weight ½ with both halves doubled is the sum).  η(F0c) =
(1 + √F0c)/(1 − √F0c) per channel, so the rough conductor's exact Fresnel has
F(0°) = F0c and rises toward 1 at grazing the way the Schlick term of the
project's model does; ``specular_reflectance`` scales the whole lobe by s.
``alpha`` is Mitsuba's GGX α (not a "roughness" to be squared), ≤ 1.  What differs from the project's cook-torrance: Mitsuba's Smith G
is separable (G1 G1) where ours is height-correlated, and the dielectric
Fresnel is exact where ours is Schlick's approximation; both small except
near grazing.  Textures are bilinear or nearest like the scene's ``filter``.

The scene (camera, lights, planes and spheres) is generated from one of the
project's scene files (``scene:``, docs/scenes.md) so Mitsuba and the ``cpu``
renderer draw the same picture; without one, a default scene (a plane of the
sample lit by a point light) is written as ``scene.yaml`` beside
``scene.xml``.  The sensor uses a stratified, unjittered sampler with the
scene's ``antialias`` count and a box filter: the same sub-pixel points the
``cpu`` renderer shades.  Integrator ``direct``: direct lighting, like the
project's renderers.  Left out: meshes and cylinders, point lights without
fall-off, materials from other stores, scene effects (environment maps).
Render with ``mitsuba scene.xml`` or ``mi.load_file`` in the ``scalar_rgb``
variant.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np

from sbrdf_core.io import write_exr

from .common import model_config, texel_grid, write_json
from .declarations import MITSUBA
from .ggx import GGXConverting, write_error_files

FORMAT = "sbrdf-mitsuba/1"
#: F0 above this is written as this (η stays finite).
MAX_F0 = 0.96

#: The scene written when none is given: the sample as a 2-unit plane under a point light, seen from above.
DEFAULT_SCENE = """\
# Written by the mitsuba exporter: the scene both scene.xml (Mitsuba) and the project's cpu renderer draw.
camera: {{position: [0.0, -1.5, 1.6], look_at: [0.0, 0.05, 0.0], up: [0, 0, 1], fov_deg: 42, resolution: [{w}, {h}]}}
materials:
  sample: {{artifact: input, filter: bilinear}}
objects:
  - {{shape: plane, size: [2.0, {sy}]}}
lights:
  - {{type: point, position: [0.7, -0.5, 1.6], intensity: 3}}
antialias: 4
"""


def eta_from_f0(f0: np.ndarray) -> np.ndarray:
    """Real index of refraction whose normal-incidence Fresnel reflectance is ``f0`` (per channel)."""
    s = np.sqrt(np.clip(f0, 0.0, MAX_F0))
    return (1.0 + s) / (1.0 - s)


def _v(x) -> str:
    return ", ".join(f"{float(a):.9g}" for a in np.asarray(x, np.float64).reshape(-1))


def _el(parent, tag: str, **attrs) -> ET.Element:
    return ET.SubElement(parent, tag, {k: str(v) for k, v in attrs.items()})


class MitsubaExporter(GGXConverting):
    """GGX-converted bitmaps and a Mitsuba 3 scene generated from a project scene file."""

    params = MITSUBA

    def __init__(self, *, scene: str | None = None, resolution: list | tuple = (256, 192), starts: int = 1,
                 iterations: int = 8, flag_error: float = 0.25,
                 max_theta_deg: float = 70.0):
        self.scene = scene
        self.resolution = tuple(int(x) for x in resolution)
        self.starts, self.iterations, self.flag_error = starts, iterations, flag_error
        self.max_theta_deg = max_theta_deg

    def convert(self, material):
        return self.ggx_maps(material)

    # -- files ---------------------------------------------------------------------------------------------

    def write(self, directory, maps, material):
        d = directory
        rho_d = np.asarray(maps["rho_d"], np.float64)
        color = np.asarray(maps["specular_color"], np.float64)
        weight = np.asarray(maps["specular"], np.float64)
        alpha = np.asarray(maps["alpha"], np.float64)
        textures = {"blend_diffuse.exr": 2.0 * np.pi * rho_d, "eta.exr": eta_from_f0(color),
                    "alpha.exr": np.repeat(alpha, 3, axis=-1), "specular.exr": np.repeat(2.0 * weight, 3, axis=-1),
                    "f0.exr": weight * color, "diffuse_albedo.exr": np.pi * rho_d}
        for name, a in textures.items():
            write_exr(os.path.join(d, name), a)
        scene_path = self.scene
        error_files, flag_attrs = write_error_files(d, maps, self.flag_error)
        files = list(textures) + error_files
        if scene_path is None:
            U, V = material.texels
            scene_path = os.path.join(d, "scene.yaml")
            with open(scene_path, "w") as f:
                f.write(DEFAULT_SCENE.format(w=self.resolution[0], h=self.resolution[1],
                                             sy=round(2.0 * float(material.size_mm[1]) / float(material.size_mm[0]), 6)))
            files.append("scene.yaml")
        root, notes = self.scene_xml(scene_path, material)
        ET.indent(root)
        ET.ElementTree(root).write(os.path.join(d, "scene.xml"), encoding="unicode", xml_declaration=True)
        files.append("scene.xml")
        desc = {"format": FORMAT, "model": material.model.name, "model_config": model_config(material),
                **texel_grid(material), "scene": os.path.abspath(scene_path), "variant": "scalar_rgb",
                "bsdf": "blendbsdf(0.5, diffuse(blend_diffuse.exr = 2 pi rho_d), roughconductor(ggx, alpha.exr, "
                        "eta.exr, k=0, specular_reflectance=specular.exr))",
                "textures": {"blend_diffuse.exr": "2 pi rho_d (the blend halves it)",
                             "eta.exr": "(1+sqrt F0c)/(1-sqrt F0c), F0c the specular colour",
                             "alpha.exr": "GGX alpha (all three channels)",
                             "specular.exr": "2 s, s the specular weight (the blend halves it)",
                             "f0.exr": "s F0c, the normal-incidence Fresnel (reference)",
                             "diffuse_albedo.exr": "pi rho_d (reference)"},
                "conversion": flag_attrs, "notes": notes}
        files.append(write_json(d, "mitsuba.json", desc))
        return {"files": files, "format": FORMAT, "scene": os.path.abspath(scene_path), **flag_attrs}

    # -- the scene -------------------------------------------------------------------------------------------

    def _registry(self):
        if self.registry is None:
            from sbrdf_core.registry import default_registry

            self.registry = default_registry()
        return self.registry

    def scene_xml(self, scene_path: str, material) -> tuple[ET.Element, list[str]]:
        """The Mitsuba XML of a project scene whose ``artifact: input`` material is the exported one."""
        from sbrdf_lib.scene import load_scene

        scene = load_scene(scene_path, registry=self._registry())
        notes = []
        if any(v is not None for v in scene.sections.values()) or scene.effects:
            raise ValueError(f"{scene_path}: the mitsuba exporter does not translate scene effects "
                             f"(environment maps, {sorted(scene.effects)})")
        if np.any(np.asarray(scene.background) != 0):
            notes.append("background colour left out (Mitsuba's is black)")
        if not scene.shadows:
            notes.append("Mitsuba always casts shadows; the project's scene has shadows off")
        root = ET.Element("scene", version="3.0.0")
        integ = _el(root, "integrator", type="direct")
        _el(integ, "integer", name="emitter_samples", value=1)
        _el(integ, "integer", name="bsdf_samples", value=1)
        cam = scene.camera
        sensor = _el(root, "sensor", type="perspective")
        _el(sensor, "float", name="fov", value=f"{cam.fov_deg:.9g}")
        _el(sensor, "string", name="fov_axis", value="y")
        t = _el(sensor, "transform", name="to_world")
        _el(t, "lookat", origin=_v(cam.position), target=_v(cam.look_at), up=_v(cam.up))
        sampler = _el(sensor, "sampler", type="stratified")
        _el(sampler, "integer", name="sample_count", value=scene.antialias)
        _el(sampler, "boolean", name="jitter", value="false")
        film = _el(sensor, "film", type="hdrfilm")
        _el(film, "integer", name="width", value=cam.resolution[0])
        _el(film, "integer", name="height", value=cam.resolution[1])
        _el(film, "string", name="pixel_format", value="rgb")
        _el(film, "rfilter", type="box")
        for lt in scene.lights:
            if lt.type == "point":
                if not lt.falloff:
                    raise ValueError(f"{scene_path}: Mitsuba's point lights fall off with distance; 'falloff: false' "
                                     "cannot be exported")
                e = _el(root, "emitter", type="point")
                x, y, z = (float(a) for a in lt.vector)
                _el(e, "point", name="position", x=x, y=y, z=z)
                _el(e, "rgb", name="intensity", value=_v(lt.power))
            else:
                e = _el(root, "emitter", type="directional")
                x, y, z = (-float(a) for a in lt.vector)  # Mitsuba: the direction light travels
                _el(e, "vector", name="direction", x=x, y=y, z=z)
                _el(e, "rgb", name="irradiance", value=_v(lt.power))
        uniform_cache: dict[str, dict] = {}
        for o in scene.objects:
            ref = scene.materials[o.material]
            if o.shape == "plane":
                sx, sy = (float(a) for a in o.params.get("size", (1.0, 1.0)))
                shape = _el(root, "shape", type="rectangle")
                m = o.matrix @ np.diag([sx / 2, sy / 2, 1.0, 1.0])
                flip = False
            elif o.shape == "sphere":
                shape = _el(root, "shape", type="sphere")
                m = o.matrix @ np.diag([float(o.params.get("radius", 1.0))] * 3 + [1.0])
                flip = True  # Mitsuba: v = θ/π; the project: v = 1 − θ/π
            else:
                raise ValueError(f"{scene_path}: shape {o.shape!r} is not exported to Mitsuba (planes and spheres are)")
            t = _el(shape, "transform", name="to_world")
            _el(t, "matrix", value=" ".join(f"{a:.9g}" for a in m.reshape(-1)))
            if ref.artifact == "input":
                self._textured_bsdf(shape, o.uv_repeat, flip, "nearest" if ref.filter == "nearest" else "bilinear")
            elif ref.model is not None and ref.surface is None:
                if o.material not in uniform_cache:
                    model = self._registry().create("brdf-model", ref.model, dict(ref.model_params))
                    uniform_cache[o.material] = self.ggx_uniform(model, ref.params)
                    notes.append(f"material {o.material!r} ({ref.model}) converted to GGX with relative error "
                                 f"{uniform_cache[o.material]['error']:.3g}")
                self._uniform_bsdf(shape, uniform_cache[o.material])
            else:
                raise ValueError(f"{scene_path}: material {o.material!r} is not the exported one nor uniform; "
                                 "export it separately")
        return root, notes

    @staticmethod
    def _bitmap(parent, name: str, file: str, uv_repeat, flip: bool, filter_type: str) -> None:
        tex = _el(parent, "texture", type="bitmap", name=name)
        _el(tex, "string", name="filename", value=file)
        _el(tex, "string", name="filter_type", value=filter_type)
        _el(tex, "boolean", name="raw", value="true")
        ru, rv = (float(a) for a in uv_repeat)
        if flip or (ru, rv) != (1.0, 1.0):
            t = _el(tex, "transform", name="to_uv")
            _el(t, "scale", x=ru, y=-rv if flip else rv)
            if flip:
                _el(t, "translate", x=0, y=rv)

    def _textured_bsdf(self, shape, uv_repeat, flip: bool, filter_type: str) -> None:
        blend = _el(shape, "bsdf", type="blendbsdf")
        _el(blend, "float", name="weight", value=0.5)
        diffuse = _el(blend, "bsdf", type="diffuse")
        self._bitmap(diffuse, "reflectance", "blend_diffuse.exr", uv_repeat, flip, filter_type)
        spec = _el(blend, "bsdf", type="roughconductor")
        _el(spec, "string", name="distribution", value="ggx")
        _el(spec, "boolean", name="sample_visible", value="true")
        self._bitmap(spec, "alpha", "alpha.exr", uv_repeat, flip, filter_type)
        self._bitmap(spec, "eta", "eta.exr", uv_repeat, flip, filter_type)
        _el(spec, "float", name="k", value=0.0)
        self._bitmap(spec, "specular_reflectance", "specular.exr", uv_repeat, flip, filter_type)

    @staticmethod
    def _uniform_bsdf(shape, g: dict) -> None:
        blend = _el(shape, "bsdf", type="blendbsdf")
        _el(blend, "float", name="weight", value=0.5)
        diffuse = _el(blend, "bsdf", type="diffuse")
        _el(diffuse, "rgb", name="reflectance", value=_v(2.0 * np.pi * g["rho_d"]))
        spec = _el(blend, "bsdf", type="roughconductor")
        _el(spec, "string", name="distribution", value="ggx")
        _el(spec, "float", name="alpha", value=f"{float(g['alpha'][0]):.9g}")
        _el(spec, "rgb", name="eta", value=_v(eta_from_f0(g["specular_color"])))
        _el(spec, "float", name="k", value=0.0)
        _el(spec, "float", name="specular_reflectance", value=f"{2.0 * float(g['specular'][0]):.9g}")


def render(scene_xml: str, spp: int | None = None) -> np.ndarray:
    """Render an exported ``scene.xml`` with Mitsuba 3 (``scalar_rgb``): linear ``(H, W, 3)`` float32."""
    from sbrdf_core.extras import require

    mi = require("mitsuba", extra="interchange", feature="rendering the mitsuba export")
    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    scene = mi.load_file(scene_xml)
    img = mi.render(scene, spp=spp) if spp else mi.render(scene)
    return np.asarray(img, np.float32)[..., :3]
