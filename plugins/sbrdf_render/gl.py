"""gl: the real-time renderer, moderngl on EGL (Mesa llvmpipe here, a GPU where there is one).

One float pass per material (McAllister's "DirectX 9-class" path, seed 000
§6.8): parameter maps in RGBA32F textures (with their MIP levels, uploaded level
by level and filtered ``GL_LINEAR_MIPMAP_LINEAR``, for ``filter: trilinear``
materials that have them), the BRDF plugin's own GLSL, every
lobe and light in one fragment shader, linear radiance into a float
framebuffer.  The display transfer is applied when the PNG is written.

The shader is generated from what the scene uses (:func:`fragment_source`):
the number of point and directional lights and their fall-off, tangent frames
only for anisotropic materials, the alpha-kill only where a material has
transparency, two-sided lighting only for transmissive models, shadow-map
lookups only when the scene asks for shadows, light-map look-ups (ρ_d·E,
Eq 4.1 of seed 004; the lights then add f_r − ρ_d) only for a scene with
``lightmap:``.  Nothing else is compiled or bound.  The GeForce 4 emulation
lives in :mod:`sbrdf_render.gf4`; walkthroughs (a moving camera,
:meth:`GLScene.set_camera`) in :mod:`sbrdf_render.walkthrough`.

Antialiasing (the scene's ``antialias: n²``, 4 unless it says) is
supersampling with the ``cpu`` renderer's pattern: the scene is drawn into a
framebuffer n times larger in each direction (every fragment centre is a
sub-sample centre ((a + ½)/n, (b + ½)/n) of an output pixel), read back as
float32 linear radiance and averaged over n×n blocks
(:meth:`~sbrdf_lib.scene.Scene.supersampled`).  MSAA would shade once per
pixel and so not converge to the reference where parameter textures change
inside a pixel, which is where the error is.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

import numpy as np

from sbrdf_core import contracts
from sbrdf_core.errors import SbrdfError
from sbrdf_core.types import RenderResult
from sbrdf_lib.gl import Drawer, Frame, check_size, clip_planes, context, device_name, parameter_exprs
from sbrdf_lib.scene import Features, downsample, load_scene
from sbrdf_lib.surface import tessellate

from . import materials as mat
from .base import SceneRenderer
from .declarations import GL

if TYPE_CHECKING:
    from .gf4 import GF4Scene

__all__ = ["Drawer", "Frame", "GLRenderer", "GLScene", "SHADOW_LOOKUP", "VERTEX", "clip_planes", "context",
           "device_name", "fragment_source", "parameter_exprs"]

logger = logging.getLogger(__name__)

# -- shader generation -------------------------------------------------------------------------------------------------

VERTEX = """#version 330
uniform mat4 u_mvp;
in vec3 in_pos;
in vec3 in_normal;
{tangent_in}in vec2 in_uv;
out vec3 v_pos;
out vec3 v_normal;
{tangent_out}out vec2 v_uv;
void main() {{
    v_pos = in_pos;
    v_normal = in_normal;
    {tangent_copy}v_uv = in_uv;
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}}
"""


def fragment_source(material: mat.SceneMaterial, features: Features, effects: tuple = ()) -> str:
    """The fragment shader for one material under the scene's lights and effects: only the code the scene needs."""
    model = material.model
    surface = material.surface  # a shading rule of its own (shading maps) replaces f_r · E · cos θ
    ntex, exprs = parameter_exprs(model, "p") if surface is None else (0, {})
    aniso = material.anisotropic
    two_sided = bool(contracts.optional(model, "two_sided", "brdf-model"))
    NP, ND = features.point_lights, features.directional_lights
    out = ["#version 330", "in vec3 v_pos;", "in vec3 v_normal;"]
    if aniso:
        out.append("in vec4 v_tangent;")
    out += ["in vec2 v_uv;", "out vec4 frag;", "uniform vec3 u_eye;"]
    out += [f"uniform sampler2D u_params_{k};" for k in range(ntex)]
    if material.alpha is not None:
        out.append("uniform sampler2D u_alpha;")
    diffuse = None
    if features.lightmap:  # diffuse from the object's light map (Eq 4.1); the lights add f_r − ρ_d
        from sbrdf_lib.lightmap import diffuse_glsl

        diffuse = diffuse_glsl(exprs) if surface is None else None
        if diffuse is None:
            raise SbrdfError(f"gl renderer: lightmap: material {material.name!r} has no rho_d or k_d; light maps "
                             "shade k_d/pi E (Eq 4.1) with the model's diffuse term")
        out += ["uniform sampler2D u_lightmap;", "uniform vec2 u_lm_repeat;"]
    if NP:
        out += [f"uniform vec3 u_point_pos[{NP}];", f"uniform vec3 u_point_power[{NP}];"]
    if ND:
        out += [f"uniform vec3 u_dir_dir[{ND}];", f"uniform vec3 u_dir_power[{ND}];"]
    if features.shadows:
        from .shadows import BIAS

        out += [f"uniform sampler2DShadow u_shadow[{NP + ND}];", f"uniform mat4 u_shadow_mvp[{NP + ND}];",
                f"const float SHADOW_BIAS = {BIAS!r};", SHADOW_LOOKUP]
    if surface is None:
        out.append(model.glsl())
        f = model.glsl_call("wi", "wo", exprs)
        if diffuse is not None:  # the Lambertian term exists where both directions are above the surface
            f = f"({f} - (wi.z > 0.0 && wo.z > 0.0 ? {diffuse} : vec3(0.0)))"
        radiance = f"{f} * E * {'abs(c)' if two_sided else 'c'}"
    else:
        out.append(surface.glsl())
        radiance = surface.glsl_radiance("wi", "wo", "E")
    body = ["void main() {"]
    if material.alpha is not None:
        body.append("    if (texture(u_alpha, v_uv).r < 0.5) discard;  // alpha-kill (seed 000 §6.5)")
    body += [f"    vec4 p_{k} = texture(u_params_{k}, v_uv);" for k in range(ntex)]
    body.append("    vec3 N = normalize(v_normal);")
    if aniso:  # per-pixel Gram–Schmidt; B from the handedness (Eq 6.1)
        body += ["    vec3 T = normalize(v_tangent.xyz - N * dot(N, v_tangent.xyz));",
                 "    vec3 B = (v_tangent.w < 0.0 ? -1.0 : 1.0) * cross(N, T);"]
    else:  # an isotropic BRDF does not care which tangent: any frame around N
        body += ["    vec3 T = normalize(cross(abs(N.z) < 0.9 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0), N));",
                 "    vec3 B = cross(N, T);"]
    body += ["    vec3 V = normalize(u_eye - v_pos);",
             "    vec3 wo = vec3(dot(T, V), dot(B, V), dot(N, V));",
             "    vec3 L = vec3(0.0);"]
    if diffuse is not None:
        body.append(f"    L += {diffuse} * texture(u_lightmap, v_uv / u_lm_repeat).rgb;  // k_d/pi E (Eq 4.1)")
    lit = "c != 0.0" if two_sided else "c > 0.0"

    def light_loop(count, setup, shadow_base):
        """One block per light, unrolled: constant indices (sampler arrays need them) and no loop overhead."""
        lines = []
        for l in range(count):
            shadow = (f" * shadow_visibility(u_shadow[{shadow_base + l}], u_shadow_mvp[{shadow_base + l}], v_pos, c)"
                      if features.shadows else "")
            lines += (["    {"] + [ln.replace("[l]", f"[{l}]") for ln in setup] +
                      ["        float c = dot(N, Lw);",
                       f"        if ({lit}) {{",
                       "            vec3 wi = vec3(dot(T, Lw), dot(B, Lw), c);",
                       f"            L += {radiance}{shadow};",
                       "        }", "    }"])
        return lines

    if NP:
        E = {"all": "u_point_power[l] / r2", "none": "u_point_power[l]",
             "mixed": "u_point_power[l] / (u_point_falloff[l] ? r2 : 1.0)"}[features.falloff]
        setup = ["        vec3 d = u_point_pos[l] - v_pos;", "        float r2 = dot(d, d);",
                 "        vec3 Lw = d * inversesqrt(r2);", f"        vec3 E = {E};"]
        if features.falloff == "mixed":
            out.append(f"uniform bool u_point_falloff[{NP}];")
        body += light_loop(NP, setup, 0)
    if ND:
        body += light_loop(ND, ["        vec3 Lw = u_dir_dir[l];", "        vec3 E = u_dir_power[l];"], NP)
    for effect in effects:  # scene effects (environment, mirrors) add their own declarations and terms to L
        decls, statements = effect.glsl(material, exprs)
        out.append(decls)
        body += statements
    body += ["    frag = vec4(L, 1.0);", "}"]
    return "\n".join(out + body) + "\n"


SHADOW_LOOKUP = """float shadow_visibility(sampler2DShadow map, mat4 mvp, vec3 p, float c) {
    vec4 q = mvp * vec4(p, 1.0);
    vec3 s = q.xyz / q.w * 0.5 + 0.5;
    if (q.w <= 0.0 || any(lessThan(s, vec3(0.0))) || any(greaterThan(s, vec3(1.0)))) return 1.0;
    float bias = SHADOW_BIAS * clamp(sqrt(max(1.0 - c * c, 0.0)) / max(c, 1e-3), 1.0, 20.0);  // slope-scaled
    return texture(map, vec3(s.xy, s.z - bias));
}
"""


# -- drawing ------------------------------------------------------------------------------------------------------------


class GLScene(Drawer):
    """A scene uploaded to the GPU: meshes, textures and one program per material.

    Build once, :meth:`draw` many times (benchmarks), :meth:`release` at the end.  With ``antialias: n²``
    everything is built for :meth:`~sbrdf_lib.scene.Scene.supersampled` (``self.scene``: the framebuffer,
    the effects, what ``drawer.scene.camera`` tells them) and :meth:`draw` returns the n×n block averages
    at the scene's own resolution; effects passed in are used as prepared.
    """

    def __init__(self, scene, materials: dict[str, mat.SceneMaterial], meshes: dict | None = None,
                 effects: list | None = None, registry=None):
        import moderngl

        from .effects import active_effects, check_covered

        self.subpixels = scene.subpixels
        scene = scene.supersampled()
        self.scene, self.materials = scene, materials
        self.ctx = ctx = context()
        check_size(ctx, scene)
        self.effects = active_effects(scene, materials, registry, ctx) if effects is None else list(effects)
        check_covered(scene, self.effects)
        W, H = scene.camera.resolution
        self._res = []
        self.fbo = self._keep(ctx.framebuffer(color_attachments=[self._keep(ctx.texture((W, H), 4, dtype="f4"))],
                                              depth_attachment=self._keep(ctx.depth_texture((W, H)))))
        self.features = scene.features(materials)
        self.sources, self.programs, self.textures = {}, {}, {}
        for name, m in materials.items():
            fs = fragment_source(m, self.features, tuple(self.effects))
            vs = VERTEX.format(tangent_in="in vec4 in_tangent;\n" if m.anisotropic else "",
                               tangent_out="out vec4 v_tangent;\n" if m.anisotropic else "",
                               tangent_copy="v_tangent = in_tangent;\n    " if m.anisotropic else "")
            self.sources[name] = (vs, fs)
            try:
                self.programs[name] = self._keep(ctx.program(vertex_shader=vs, fragment_shader=fs))
            except moderngl.Error as e:
                raise SbrdfError(f"gl renderer: the shader for material {name!r} (model {m.model.name!r}) does not "
                                 f"compile:\n{e}") from None
            self.textures[name] = self._upload_material(m)
        meshes = meshes if meshes is not None else {}
        self.vaos = []
        self.triangles = 0
        for k, obj in enumerate(scene.objects):
            mesh = meshes.get(k) or tessellate(obj)
            meshes[k] = mesh
            m = materials[obj.material]
            prog = self.programs[obj.material]
            cols = [mesh.positions, mesh.normals] + ([mesh.tangents] if m.anisotropic else []) + [mesh.uvs]
            names = ["in_pos", "in_normal"] + (["in_tangent"] if m.anisotropic else []) + ["in_uv"]
            # attributes the compiler dropped (a light-mapped Lambertian shader needs no normal) become padding
            fmt = " ".join(f"{c.shape[1]}f" if nm in prog else f"{c.shape[1]}x4" for c, nm in zip(cols, names))
            names = [nm for nm in names if nm in prog]
            vbo = self._keep(ctx.buffer(np.concatenate(cols, axis=1).astype("f4").tobytes()))
            ibo = self._keep(ctx.buffer(mesh.indices.astype("u4").tobytes()))
            self.vaos.append((obj.material, self._keep(ctx.vertex_array(prog, [(vbo, fmt, *names)], ibo))))
            self.triangles += mesh.triangles
        self.meshes = meshes
        self.lightmaps: list = []
        if self.features.lightmap:
            from sbrdf_lib.lightmap import load_maps

            for _, E in sorted(load_maps(scene).items()):
                t = self._keep(ctx.texture((E.shape[1], E.shape[0]), 3, np.ascontiguousarray(E, "f4").tobytes(),
                                           dtype="f4"))
                t.filter = (moderngl.LINEAR, moderngl.LINEAR)
                t.repeat_x = t.repeat_y = False
                self.lightmaps.append(t)
        self.shadow = None
        if self.features.shadows:
            from .shadows import ShadowMaps

            self.shadow = ShadowMaps(ctx, scene, meshes)
            self._res.append(self.shadow)
        for effect in self.effects:
            effect.gl_prepare(self)
            self._res.append(effect)
        self.query = self._keep(ctx.query(time=True))
        self._set_uniforms()

    def _upload_material(self, m: mat.SceneMaterial) -> list:
        """``[(sampler uniform, texture)]`` of one material, in texture-unit order."""
        import moderngl

        ctx = self.ctx
        if m.surface is not None:
            return [(name, self._keep(t)) for name, t in m.surface.gl_textures(ctx)]
        V, U, K = m.maps.shape
        ntex = (K + 3) // 4
        padded = np.zeros((V, U, ntex * 4), np.float32)
        padded[..., :K] = m.maps
        filt = (moderngl.NEAREST, moderngl.NEAREST) if m.filter == "nearest" else (moderngl.LINEAR, moderngl.LINEAR)
        levels = []
        if m.trilinear:  # real MIP levels: the Mip node's, each uploaded to its GL level, GL_LINEAR_MIPMAP_LINEAR
            for lv in m.levels:
                p = np.zeros(lv.shape[:2] + (ntex * 4,), np.float32)
                p[..., :K] = lv
                levels.append(p)
            filt = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        texs = []
        for k in range(ntex):
            t = self._keep(ctx.texture((U, V), 4, np.ascontiguousarray(padded[..., 4 * k:4 * k + 4]).tobytes(), dtype="f4"))
            if levels:
                t.build_mipmaps(0, len(levels))  # allocates levels 1 … L and sets GL_TEXTURE_MAX_LEVEL = L
                for l, p in enumerate(levels, 1):
                    t.write(np.ascontiguousarray(p[..., 4 * k:4 * k + 4]).tobytes(), level=l)
                t.anisotropy = 1.0
            t.filter = filt
            t.repeat_x = t.repeat_y = True
            texs.append((f"u_params_{k}", t))
        if m.alpha is not None and levels:
            filt = (moderngl.LINEAR, moderngl.LINEAR)
        if m.alpha is not None:
            t = self._keep(ctx.texture((U, V), 1, np.ascontiguousarray(m.alpha, np.float32).tobytes(), dtype="f4"))
            t.filter = filt
            texs.append(("u_alpha", t))
        # Material-wide textures a model declares for its own GLSL (separable factors); it filters them itself.
        for uniform, array in ((contracts.optional(m.model, "gl_textures", "brdf-model") or dict)() or {}).items():
            a = np.ascontiguousarray(array, np.float32)
            t = self._keep(ctx.texture((a.shape[1], a.shape[0]), a.shape[2], a.tobytes(), dtype="f4"))
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
            texs.append((uniform, t))
        return texs

    def _set_uniforms(self) -> None:
        scene = self.scene
        view, proj = scene.camera.matrices(*clip_planes(scene.camera, self.meshes))
        mvp = (proj @ view).astype("f4")
        points = [lt for lt in scene.lights if lt.type == "point"]
        dirs = [lt for lt in scene.lights if lt.type == "directional"]
        for name, prog in self.programs.items():
            def put(uniform, data, prog=prog):  # the compiler drops what a variant does not use (lit Lambertian)
                if uniform in prog:
                    prog[uniform].write(np.ascontiguousarray(data).tobytes())

            put("u_mvp", mvp.T)
            put("u_eye", np.asarray(scene.camera.position, "f4"))
            if points:
                put("u_point_pos", np.array([lt.vector for lt in points], "f4"))
                put("u_point_power", np.array([lt.power for lt in points], "f4"))
                put("u_point_falloff", np.array([lt.falloff for lt in points], "i4"))
            if dirs:
                put("u_dir_dir", np.array([lt.vector for lt in dirs], "f4"))
                put("u_dir_power", np.array([lt.power for lt in dirs], "f4"))
            unit = 0
            for uniform, _ in self.textures[name]:
                prog[uniform].value = unit
                unit += 1
            if self.lightmaps:
                if "u_lightmap" in prog:
                    prog["u_lightmap"].value = unit
                unit += 1
            surface = self.materials[name].surface
            for uniform, value in (surface.gl_uniforms() if surface is not None else {}).items():
                if uniform in prog:  # the compiler drops what the variant does not use
                    prog[uniform].write(np.asarray(value, "f4").tobytes())
            if self.shadow is not None:
                self.shadow.set_uniforms(prog, unit)
                unit += len(self.shadow.maps)
            for effect in self.effects:
                unit += effect.gl_uniforms(prog, unit)

    def set_camera(self, camera) -> None:
        """Move the camera (walkthroughs): uniforms, and effects that follow it (``gl_camera(drawer)``, optional).

        ``camera``'s resolution is ignored: the framebuffer keeps its size.
        """
        import dataclasses

        self.scene = dataclasses.replace(self.scene, camera=dataclasses.replace(
            camera, resolution=self.scene.camera.resolution))
        for effect in self.effects:
            follow = getattr(effect, "gl_camera", None)  # effects of this repository; not in the contract yet
            if callable(follow):
                follow(self)
        self._set_uniforms()

    def draw(self, read: bool = True) -> Frame:
        import moderngl

        ctx = self.ctx
        t0 = time.perf_counter()
        if self.shadow is not None:
            self.shadow.render()
        for effect in self.effects:
            effect.gl_frame(self)
        self.fbo.use()
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        bg = tuple(float(x) for x in self.scene.background)
        with self.query:
            self.fbo.clear(*bg, 0.0, depth=1.0)
            for k, (name, vao) in enumerate(self.vaos):
                unit = 0
                for _, t in self.textures[name]:
                    t.use(unit)
                    unit += 1
                if self.lightmaps:
                    self.lightmaps[k].use(unit)
                    if "u_lm_repeat" in self.programs[name]:
                        self.programs[name]["u_lm_repeat"].value = tuple(float(x) for x in self.scene.objects[k].uv_repeat)
                    unit += 1
                if self.shadow is not None:
                    self.shadow.use(unit)
                    unit += len(self.shadow.maps)
                for effect in self.effects:
                    unit += effect.gl_use(unit)
                vao.render(moderngl.TRIANGLES)
        image, gpu, wall = self._finish(self.fbo, t0, read)
        if image is not None:
            image = downsample(image, self.subpixels)
        return Frame(image, gpu, wall, {"triangles": self.triangles, "antialias": self.subpixels ** 2})


class GLRenderer(SceneRenderer):
    """``Render`` plugin ``gl``: the scene file drawn by :class:`GLScene` (or the GeForce 4 emulation)."""

    params = GL

    def __init__(self, *, scene: str, exposure: float | None = None, pipeline: str = "float", frames: int = 1):
        super().__init__(scene=scene, exposure=exposure)
        self.pipeline, self.frames = pipeline, frames

    def prepare(self, material) -> dict:
        """The store-backed materials' maps and, for ``geforce4``, their 8-bit hardware textures, lazy."""
        out = super().prepare(material)
        if self.pipeline == "geforce4":
            from .gf4 import prepare_hardware

            scene = load_scene(self.scene_path, registry=self.registry)
            out.update(prepare_hardware(scene, material, self._registry()))
        return out

    def render_path(self, material, out_dir: str, **options) -> dict:
        """The scene's camera path as frames and a video in ``out_dir`` (:func:`sbrdf_render.walkthrough.render_path`)."""
        from .walkthrough import render_path

        if self.pipeline != "float":
            raise SbrdfError("walkthroughs are drawn by the float pipeline")
        scene, materials = self.load(material)
        return render_path(scene, materials, out_dir, registry=self._registry(),
                           exposure=self.exposure, **options)

    def render(self, material, prepared: dict | None = None) -> RenderResult:
        scene, materials = self.load(material, prepared)
        drawer: GF4Scene | GLScene
        if self.pipeline == "geforce4":
            if scene.lightmapped:
                raise SbrdfError(f"{scene.file}: the geforce4 pipeline draws no light maps; use pipeline: float")
            if scene.section("environment") is not None:
                raise SbrdfError(f"{scene.file}: the geforce4 pipeline draws point and directional lights only; "
                                 "use pipeline: float for environment lighting")
            from .gf4 import GF4Scene

            check_size(context(), scene.supersampled())
            drawer = GF4Scene(scene.supersampled(), materials, registry=self._registry(),
                              prepared=prepared)  # antialiased as the float path: n×n block means
        else:
            drawer = GLScene(scene, materials, registry=self.registry)
        try:
            frames = [drawer.draw(read=(i == self.frames - 1)) for i in range(self.frames)]
        finally:
            drawer.release()
        gpu = [f.gpu_ms for f in frames]
        logger.info("gl render of %s (%s): %d frame(s), median %.2f GPU ms", self.scene_path, self.pipeline,
                    len(frames), float(np.median(gpu)))
        image = frames[-1].image
        assert image is not None, "the last frame is read back"
        if self.pipeline == "geforce4":
            image = downsample(image, scene.subpixels)
        return self.result(scene, image, {"antialias": scene.antialias,
            "device": device_name(), "pipeline": self.pipeline, "gpu_ms": gpu, "gpu_ms_median": float(np.median(gpu)),
            "triangles": frames[-1].stats["triangles"]})
