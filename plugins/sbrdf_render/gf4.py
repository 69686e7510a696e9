"""gf4: McAllister's GeForce 4 SBRDF shader (seed 000 §6.7), emulated in moderngl for comparison.

Two passes per lobe per light (Table 6.2: 2 × lobes × lights), additive blending:

* **Pass 1** (the p-buffer): the vertex program puts ω_i and ω_r into the
  tangent frame (T from the mesh, B = w · N × T), unnormalised; the fragment
  renormalises them, fetches (C, n') from the 8-bit lobe texture and writes
  x' = clamp(x, 0, 1)², x = (C ⊙ ω_i) · ω_r, with n' in alpha, into an
  **RGBA8** target, so the p-buffer's 8-bit rounding of x' and n' is real.
* **Pass 2**: reads that target at ``gl_FragCoord`` (Eq 6.12's
  un-perspective-corrected screen coordinates), does the dependent read
  s = T[x', n'] in the 256×256 8-bit exponent table
  (the ``mcallister8`` quantizer's ``exponent_table()``, NEAREST), and adds
  (ρ_d δ(j, 1) + ρ_s,j · s) · E_l to the frame; E_l, the light's irradiance
  power × clamp(N·ω_l, 0) [/ d²], is computed per vertex (COL0), as the text
  does.  Texels whose ρ_d alpha is below ½ are killed in both passes.
* **Shadows** (scenes with ``shadows: true``): the ``gl`` path's shadow maps
  (:mod:`~sbrdf_render.shadows`, one depth pass per light before the frame;
  the GeForce 3/4 sampled depth textures with a hardware compare), looked up
  in pass 2, which multiplies light l's contribution by its visibility.

The parameters are the ``mcallister8`` textures (RGBA8/RGB8, normalised):
the material's own when it came from an ``mcallister8`` TextureSet, otherwise
its parameter maps encoded on the fly with that quantizer's defaults.  The
per-pixel result equals the ``mcallister8`` plugin's ``hardware_shade``
up to 8-bit rounding ties (tests/plugins/test_render_gf4.py), so it shows the
documented artifacts: no brightening at grazing (x clamped at 1), banding in
highlight tails (x', n' rounded to 8 bits), exponents above 255 clamped.

Where the emulation is kinder than the card (docs/render-gf4.md): the frame
is RGBA16F (the card blended into 8 bits; the EXR keeps values above 1), the
irradiance is a float varying (COL0 was clamped to [0, 1]), and directions
are renormalised in float (the card used an 8-bit normalisation cube map).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_lib.gl import Drawer, Frame, clip_planes, context
from sbrdf_lib.surface import tessellate

from . import materials as mat
from .gl import SHADOW_LOOKUP

logger = logging.getLogger(__name__)

#: Texture units: the same in both passes' programs.
UNIT_LOBE, UNIT_RHO_S, UNIT_RHO_D, UNIT_PBUFFER, UNIT_TABLE, UNIT_SHADOW = 0, 1, 2, 3, 4, 5

VERTEX = """#version 330
uniform mat4 u_mvp;
uniform vec3 u_eye;
uniform vec4 u_light;  // xyz: position (w = 1) or unit direction towards the light (w = 0)
uniform vec3 u_power;
uniform float u_falloff;  // 1: E = I cos / d²; 0: E = I cos
in vec3 in_pos;
in vec3 in_normal;
in vec4 in_tangent;
in vec2 in_uv;
out vec2 v_uv;
{outputs}
invariant gl_Position;  // both passes must rasterise identical depths (LEQUAL with depth writes off)
void main() {{
    vec3 N = normalize(in_normal);
    vec3 L = u_light.w > 0.5 ? u_light.xyz - in_pos : u_light.xyz;
    vec3 V = u_eye - in_pos;
{body}
    v_uv = in_uv;
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}}
"""

# Pass 1's vertex program: B from N and T, ω_i (TEX1) and ω_r (TEX2) in the tangent frame, unnormalised.
PASS1_VS = VERTEX.format(outputs="out vec3 v_wi;\nout vec3 v_wo;", body="""\
    vec3 T = normalize(in_tangent.xyz - N * dot(N, in_tangent.xyz));
    vec3 B = (in_tangent.w < 0.0 ? -1.0 : 1.0) * cross(N, T);
    v_wi = vec3(dot(T, L), dot(B, L), dot(N, L));
    v_wo = vec3(dot(T, V), dot(B, V), dot(N, V));""")

# Pass 2's vertex program: the light's irradiance per vertex (COL0), and N·V to drop back-facing views; with
# shadows also the world position and normal, for the shadow-map lookup.
def pass2_vertex(shadows: bool = False) -> str:
    outputs = "out vec3 v_irradiance;\nout float v_ndotv;"
    if shadows:
        outputs += "\nout vec3 v_pos;\nout vec3 v_normal;"
    body = """\
    float d2 = dot(L, L);
    float c = max(dot(N, L * inversesqrt(d2)), 0.0);
    v_irradiance = u_power * c / (u_falloff > 0.5 ? d2 : 1.0);
    v_ndotv = dot(N, V);"""
    if shadows:
        body += "\n    v_pos = in_pos;\n    v_normal = N;"
    return VERTEX.format(outputs=outputs, body=body)


PASS2_VS = pass2_vertex()


def pass1_source(alpha: bool) -> str:
    kill = "    if (texture(u_rho_d, v_uv).a < 0.5) discard;\n" if alpha else ""
    return f"""#version 330
in vec3 v_wi;
in vec3 v_wo;
in vec2 v_uv;
uniform sampler2D u_lobe;  // C_x, C_y, C_z biased, n' in alpha
{"uniform sampler2D u_rho_d;" if alpha else ""}
uniform vec3 u_c_scale;  // C = texel * u_c_scale + u_c_bias (the quantizer's scale × 255 and bias)
uniform vec3 u_c_bias;
out vec4 frag;
void main() {{
{kill}    vec4 t = texture(u_lobe, v_uv);
    vec3 C = t.rgb * u_c_scale + u_c_bias;
    vec3 wi = normalize(v_wi);
    vec3 wo = normalize(v_wo);
    float x = dot(C * wi, wo);
    float xc = (wi.z > 0.0 && wo.z > 0.0) ? clamp(x, 0.0, 1.0) : 0.0;  // the combiners clamp x at 1
    frag = vec4(vec3(xc * xc), t.a);  // RGBA8 target: x' = x² and n' rounded to 8 bits, as in the p-buffer
}}
"""


def pass2_source(alpha: bool, shadows: bool = False) -> str:
    kill = "    if (rho_d.a < 0.5) discard;  // alpha-kill (seed 000 §6.5)\n" if alpha else ""
    if shadows:
        from .shadows import BIAS

        # this pass's light: its shadow map and matrix (bound per light), c = N·ω_l for the slope-scaled bias
        shadow_decl = ("in vec3 v_pos;\nin vec3 v_normal;\nuniform vec4 u_light;\nuniform sampler2DShadow u_shadow;\n"
                       f"uniform mat4 u_shadow_mvp;\nconst float SHADOW_BIAS = {BIAS!r};\n{SHADOW_LOOKUP}")
        visibility = """    vec3 Ls = normalize(u_light.w > 0.5 ? u_light.xyz - v_pos : u_light.xyz);
    float vis = shadow_visibility(u_shadow, u_shadow_mvp, v_pos, dot(normalize(v_normal), Ls));
"""
    else:
        shadow_decl, visibility = "", "    float vis = 1.0;\n"
    return f"""#version 330
in vec3 v_irradiance;
in float v_ndotv;
in vec2 v_uv;
{shadow_decl}uniform sampler2D u_pbuffer;
uniform sampler2D u_table;  // T[x', n'], 8 bits, NEAREST
uniform sampler2D u_rho_s;
uniform sampler2D u_rho_d;
uniform float u_first_lobe;  // ρ_d δ(j, 1)
out vec4 frag;
void main() {{
    vec4 rho_d = texture(u_rho_d, v_uv);
{kill}    vec4 p = texelFetch(u_pbuffer, ivec2(gl_FragCoord.xy), 0);  // this fragment's p-buffer pixel
    float s = texture(u_table, vec2(p.a, p.r)).r;  // dependent read: column n', row x'
    vec3 f = u_first_lobe * rho_d.rgb + texture(u_rho_s, v_uv).rgb * s;
{visibility}    frag = vec4(v_ndotv > 0.0 ? f * v_irradiance * vis : vec3(0.0), 1.0);
}}
"""


def _lafortune(model) -> bool:
    return getattr(model, "name", "") == "lafortune" and hasattr(model, "lobe_list")


def _quantizer(registry):
    """The ``mcallister8`` quantizer, through the registry: its layout is the GeForce 4's."""
    if registry is None:
        from sbrdf_core.registry import default_registry

        registry = default_registry()
    return registry.create("quantizer", "mcallister8", {})


def _encode(quantizer, name: str, model, params: dict):
    try:
        return quantizer.encode(params, model)
    except ValueError as err:
        raise SbrdfError(f"gl renderer, pipeline geforce4: material {name!r}: {err}") from None


def prepare_hardware(scene, input_material, registry) -> dict:
    """The 8-bit textures the geforce4 path encodes from float maps, lazy, keyed ``<material>/gf4/<texture>``.

    Store-backed maps are cast to float32 as :func:`materials.from_material` packs them, so the codes
    equal those :func:`hardware_textures` would compute from the packed maps; materials the path
    refuses are left to :func:`hardware_textures` to report.
    """
    import dask.array as da
    from dask.base import is_dask_collection

    stored = mat.inputs(scene, input_material, registry)
    quantizer = _quantizer(registry)
    out = {}
    for name in sorted({o.material for o in scene.objects}):
        ref = scene.materials[name]
        try:
            if name in stored:
                m = stored[name]
                model = m.model
                if (m.encoded or {}).get("quantizer") == "mcallister8" or not _lafortune(model):
                    continue
                params = {p.name: m.params[p.name].astype(np.float32).astype(np.float64) for p in model.parameters}
            elif ref.artifact is None:
                model = registry.create("brdf-model", ref.model, dict(ref.model_params))
                if not _lafortune(model):
                    continue
                maps = mat.uniform(name, model, ref.params, ref.filter).maps
                params, off = {}, 0
                for p in model.parameters:
                    params[p.name] = da.from_array(np.asarray(maps[..., off:off + p.channels], np.float64))
                    off += p.channels
            else:
                continue
            e = _encode(quantizer, name, model, params)
        except SbrdfError:
            continue  # refused again, with its message, when the scene is drawn
        out.update({f"{name}/gf4/{k}": t for k, t in e.textures.items() if is_dask_collection(t)})
    return out


def hardware_textures(m: mat.SceneMaterial, quantizer=None, computed: dict | None = None) -> dict:
    """The material's ``mcallister8`` textures, scale and bias (its own, or its maps encoded now).

    ``computed``: :func:`prepare_hardware` computed (the runner's prepare step); ``quantizer``: the
    ``mcallister8`` quantizer (default: from the installed plugins).
    """
    if not _lafortune(m.model):
        raise SbrdfError(f"gl renderer, pipeline geforce4: material {m.name!r} uses model {m.model.name!r}; the "
                         "GeForce 4 path renders Lafortune lobes only (use pipeline: float)")
    enc = m.encoded
    if enc is not None and enc.get("quantizer") == "mcallister8":
        return {"textures": {k: np.asarray(t) for k, t in enc["textures"].items()},
                "scale": {k: np.asarray(s, np.float64) for k, s in enc["scale"].items()},
                "bias": {k: np.asarray(b, np.float64) for k, b in enc["bias"].items()}}
    import dask.array as da

    quantizer = quantizer if quantizer is not None else _quantizer(None)
    params, off = {}, 0
    for p in m.model.parameters:
        params[p.name] = da.from_array(np.asarray(m.maps[..., off:off + p.channels], np.float64))
        off += p.channels
    e = _encode(quantizer, m.name, m.model, params)
    textures = {}
    for k, t in e.textures.items():
        key = f"{m.name}/gf4/{k}"
        if computed is not None and key in computed:
            textures[k] = np.asarray(computed[key])
        else:  # direct use (tests, benchmarks): no runner computed it
            textures[k] = np.asarray(t.compute() if hasattr(t, "compute") else t)
    if m.alpha is not None:
        textures["rho_d"] = textures["rho_d"].copy()
        textures["rho_d"][..., 3] = np.clip(np.round(255.0 * m.alpha), 0, 255).astype(np.uint8)
    return {"textures": textures, "scale": dict(e.scale), "bias": dict(e.bias)}


class GF4Scene(Drawer):
    """A scene uploaded for the two-pass GeForce 4 path: same interface as :class:`~sbrdf_render.gl.GLScene`."""

    def __init__(self, scene, materials: dict[str, mat.SceneMaterial], meshes: dict | None = None, registry=None,
                 prepared: dict | None = None):
        import moderngl

        self.scene, self.materials = scene, materials
        if scene.section("environment") is not None:
            raise SbrdfError(f"{scene.file}: the geforce4 pipeline draws point and directional lights only")
        quantizer = _quantizer(registry)
        table_of = getattr(quantizer, "exponent_table", None)  # the hardware's lookup table, from its layout's owner
        if table_of is None:
            raise SbrdfError("gl renderer, pipeline geforce4: the mcallister8 quantizer plugin does not provide "
                             "exponent_table()")
        # refuse before allocating GL objects
        hardware = {name: hardware_textures(m, quantizer, prepared) for name, m in materials.items()}
        self.ctx = ctx = context()
        W, H = scene.camera.resolution
        self._res = []
        depth = self._keep(ctx.depth_texture((W, H)))
        self.frame = self._keep(ctx.framebuffer([self._keep(ctx.texture((W, H), 4, dtype="f2"))], depth))
        self.pbuffer_tex = self._keep(ctx.texture((W, H), 4, dtype="f1"))  # RGBA8: the p-buffer's precision
        self.pbuffer_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.pbuffer = self._keep(ctx.framebuffer([self.pbuffer_tex], depth))
        table = np.ascontiguousarray(table_of())  # row i = x', column j = n'
        self.table = self._keep(ctx.texture((256, 256), 1, table.tobytes(), dtype="f1"))
        self.table.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.table.repeat_x = self.table.repeat_y = False
        self.sources, self.programs, self.textures, self.lobes = {}, {}, {}, {}
        shadows = bool(scene.shadows)
        pass2_vs = pass2_vertex(shadows)
        for name, m in materials.items():
            alpha = m.alpha is not None
            self.sources[name] = (PASS1_VS, pass1_source(alpha), pass2_vs, pass2_source(alpha, shadows))
            try:
                p1 = self._keep(ctx.program(vertex_shader=PASS1_VS, fragment_shader=pass1_source(alpha)))
                p2 = self._keep(ctx.program(vertex_shader=pass2_vs, fragment_shader=pass2_source(alpha, shadows)))
            except moderngl.Error as e:
                raise SbrdfError(f"gl renderer, pipeline geforce4: the shaders for material {name!r} do not "
                                 f"compile:\n{e}") from None
            self.programs[name] = (p1, p2)
            self.lobes[name] = m.model.lobes
            self.textures[name] = self._upload(hardware[name], m)
            for prog in (p1, p2):
                for uniform, unit in (("u_lobe", UNIT_LOBE), ("u_rho_s", UNIT_RHO_S), ("u_rho_d", UNIT_RHO_D),
                                      ("u_pbuffer", UNIT_PBUFFER), ("u_table", UNIT_TABLE),
                                      ("u_shadow", UNIT_SHADOW)):
                    if uniform in prog:
                        prog[uniform].value = unit
        self.max_lobes = max([1] + list(self.lobes.values()))
        meshes = meshes if meshes is not None else {}
        self.vaos, self.triangles = [], 0
        for k, obj in enumerate(scene.objects):
            mesh = meshes.get(k) or tessellate(obj)
            meshes[k] = mesh
            data = np.concatenate([mesh.positions, mesh.normals, mesh.tangents, mesh.uvs], axis=1).astype("f4")
            vbo = self._keep(ctx.buffer(data.tobytes()))
            ibo = self._keep(ctx.buffer(mesh.indices.astype("u4").tobytes()))
            # pass 2 has no use for the tangent: skip_errors lets its program ignore that attribute
            layout = [(vbo, "3f 3f 4f 2f", "in_pos", "in_normal", "in_tangent", "in_uv")]
            pair = tuple(self._keep(ctx.vertex_array(prog, layout, ibo, skip_errors=True))
                         for prog in self.programs[obj.material])
            self.vaos.append((obj.material, pair))
            self.triangles += mesh.triangles
        self.meshes = meshes
        self.shadow = None
        if shadows:  # the gl path's shadow maps: one depth map per light, rendered at the start of each frame
            from .shadows import ShadowMaps

            self.shadow = ShadowMaps(ctx, scene, meshes)
            self._res.append(self.shadow)
        self.query = self._keep(ctx.query(time=True))
        self._set_uniforms()

    def _upload(self, hw: dict, m: mat.SceneMaterial) -> dict:
        """RGBA8/RGB8 normalised textures per lobe (a lobe-less material gets a zero ρ_s), with C's decode."""
        import moderngl

        filt = (moderngl.NEAREST, moderngl.NEAREST) if m.filter == "nearest" else (moderngl.LINEAR, moderngl.LINEAR)

        def tex(a):
            a = np.ascontiguousarray(a, np.uint8)
            t = self._keep(self.ctx.texture((a.shape[1], a.shape[0]), a.shape[2], a.tobytes(), dtype="f1", alignment=1))
            t.filter = filt
            t.repeat_x = t.repeat_y = True
            return t

        textures, scale, bias = hw["textures"], hw["scale"], hw["bias"]
        out = {"rho_d": tex(textures["rho_d"]), "lobes": []}
        for j in range(1, max(1, m.model.lobes) + 1):
            if f"lobe_{j}" in textures:
                c_scale = tuple(float(s) * 255.0 for s in scale[f"lobe_{j}"][:3])
                c_bias = tuple(float(b) for b in bias[f"lobe_{j}"][:3])
                out["lobes"].append((tex(textures[f"lobe_{j}"]), tex(textures[f"rho_s_{j}"]), c_scale, c_bias))
            else:  # no lobes: ρ_d only, drawn in lobe 1's passes with ρ_s = 0
                zero = np.zeros((1, 1, 4), np.uint8)
                out["lobes"].append((tex(zero), tex(zero[..., :3]), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
        return out

    def _set_uniforms(self) -> None:
        scene = self.scene
        view, proj = scene.camera.matrices(*clip_planes(scene.camera, self.meshes))
        mvp = (proj @ view).astype("f4")
        for p1, p2 in self.programs.values():
            for prog in (p1, p2):
                prog["u_mvp"].write(mvp.T.tobytes())
                if "u_eye" in prog:
                    prog["u_eye"].value = tuple(float(x) for x in scene.camera.position)

    def _light(self, prog, light) -> None:
        for name, value in (("u_light", (*(float(x) for x in light.vector), 1.0 if light.type == "point" else 0.0)),
                            ("u_power", tuple(float(x) for x in light.power)),
                            ("u_falloff", 1.0 if (light.type == "point" and light.falloff) else 0.0)):
            if name in prog:
                prog[name].value = value

    def draw(self, read: bool = True) -> Frame:
        import moderngl

        ctx = self.ctx
        t0 = time.perf_counter()
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ONE
        bg = tuple(float(x) for x in self.scene.background)
        passes = 0
        if self.shadow is not None:
            self.shadow.render()  # binds the shadow framebuffers; the frame and p-buffer are bound below
        with self.query:
            self.frame.depth_mask = self.pbuffer.depth_mask = True
            self.frame.use()
            self.frame.clear(*bg, 0.0, depth=1.0)
            ctx.depth_func = "<"
            for li, light in enumerate(self.scene.lights):
                for j in range(1, self.max_lobes + 1):
                    first = li == 0 and j == 1
                    # pass 1: x', n' into the p-buffer (the very first pass also lays the depth)
                    self.pbuffer.use()
                    ctx.disable(moderngl.BLEND)  # x', n' replace the p-buffer's previous pass
                    for name, (vao1, _) in self.vaos:
                        if j > max(1, self.lobes[name]):
                            continue
                        lobe, _, c_scale, c_bias = self.textures[name]["lobes"][j - 1]
                        p1 = self.programs[name][0]
                        self._light(p1, light)
                        p1["u_c_scale"].value, p1["u_c_bias"].value = c_scale, c_bias
                        lobe.use(UNIT_LOBE)
                        self.textures[name]["rho_d"].use(UNIT_RHO_D)
                        vao1.render(moderngl.TRIANGLES)
                    passes += 1
                    if first:
                        self.frame.depth_mask = self.pbuffer.depth_mask = False
                        ctx.depth_func = "<="
                    # pass 2: table lookup, × ρ_s (+ ρ_d on lobe 1), × irradiance, added to the frame
                    self.frame.use()
                    if not first:  # the first pass 2 overwrites the background where a surface is; then add
                        ctx.enable(moderngl.BLEND)
                    self.pbuffer_tex.use(UNIT_PBUFFER)
                    self.table.use(UNIT_TABLE)
                    if self.shadow is not None:
                        self.shadow.maps[li].use(UNIT_SHADOW)
                    for name, (_, vao2) in self.vaos:
                        if j > max(1, self.lobes[name]):
                            continue
                        _, rho_s, _, _ = self.textures[name]["lobes"][j - 1]
                        p2 = self.programs[name][1]
                        self._light(p2, light)
                        if self.shadow is not None:
                            p2["u_shadow_mvp"].write(self.shadow.matrices[li].T.tobytes())
                        p2["u_first_lobe"].value = 1.0 if j == 1 else 0.0
                        rho_s.use(UNIT_RHO_S)
                        self.textures[name]["rho_d"].use(UNIT_RHO_D)
                        vao2.render(moderngl.TRIANGLES)
                    passes += 1
        ctx.disable(moderngl.BLEND)
        ctx.depth_func = "<"
        self.frame.depth_mask = self.pbuffer.depth_mask = True
        image, gpu, wall = self._finish(self.frame, t0, read)
        return Frame(image, gpu, wall, {"triangles": self.triangles, "passes": passes,
                                        "lobes": self.max_lobes, "lights": len(self.scene.lights)})
