"""GL side of the ``mirror`` effect: the mirrored-camera pass and the reflector's sampling code (Mühlbacher §4.5)."""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError

from . import cubemap, lobes
from .glsl import ESTIMATORS, atlas_texture, beckmann_loop, cosine_ring_loop, pattern_decls

PASS_VS = """#version 330
uniform mat4 u_mvp;
uniform vec4 u_clip;
in vec3 in_pos;
in vec3 in_normal;
in vec2 in_uv;
out vec3 v_pos;
out vec3 v_normal;
out vec2 v_uv;
out float gl_ClipDistance[1];
void main() {
    v_pos = in_pos;
    v_normal = in_normal;
    v_uv = in_uv;
    gl_ClipDistance[0] = dot(vec4(in_pos, 1.0), u_clip);  // keep what lies in front of the reflector
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}
"""


BACKGROUND_VS = """#version 330
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 1.0, 1.0); }
"""


def background_fragment(size: int) -> str:
    """Where the mirrored view sees no geometry: the environment along the reflected camera ray, no position."""
    top = float(np.log2(size))
    return f"""#version 330
layout(location = 0) out vec4 o_rad;
layout(location = 1) out vec4 o_pos;
layout(location = 2) out vec4 o_nrm;
uniform vec2 u_res;
uniform vec3 u_right;
uniform vec3 u_up;
uniform vec3 u_forward;
uniform vec3 u_plane_n;
uniform sampler2D u_mir_env;
{cubemap.GLSL}
void main() {{
    vec2 ndc = gl_FragCoord.xy / u_res * 2.0 - 1.0;
    vec3 d = normalize(u_forward + ndc.x * u_right + ndc.y * u_up);  // the camera's ray through this pixel
    vec3 w = d - 2.0 * dot(d, u_plane_n) * u_plane_n;                   // reflected about the plane
    o_rad = vec4(atlas_lod(u_mir_env, w, 0.0, {float(size)!r}, {top!r}), 1.0);
    o_pos = vec4(0.0);
    o_nrm = vec4(0.0);
}}
"""


def pass_fragment(material, NP: int, ND: int, env_D: int = 0, lightmap: bool = False) -> str:
    """Diffuse-only radiance, world position and normal of the mirrored view (three colour attachments).

    ``env_D``: face size of the environment's D(N) map (``u_mir_D``), 0 without an environment;
    ``lightmap``: the radiance is ρ_d·E from the object's light map instead (lights and environment are in it).
    """
    if lightmap:
        NP = ND = env_D = 0
    from sbrdf_lib.gl import parameter_exprs
    from sbrdf_lib.lightmap import diffuse_glsl

    ntex, exprs = parameter_exprs(material.model, "p")
    rho_d = diffuse_glsl(exprs)
    if rho_d is None:
        raise SbrdfError(f"mirror: material {material.name!r} (model {material.model.name!r}) has no rho_d for the "
                         "diffuse-only mirror pass")
    out = ["#version 330", "in vec3 v_pos;", "in vec3 v_normal;", "in vec2 v_uv;",
           "layout(location = 0) out vec4 o_rad;", "layout(location = 1) out vec4 o_pos;",
           "layout(location = 2) out vec4 o_nrm;"]
    out += [f"uniform sampler2D u_params_{k};" for k in range(ntex)]
    if NP:
        out += [f"uniform vec3 u_point_pos[{NP}];", f"uniform vec3 u_point_power[{NP}];",
                f"uniform float u_point_falloff[{NP}];"]
    if ND:
        out += [f"uniform vec3 u_dir_dir[{ND}];", f"uniform vec3 u_dir_power[{ND}];"]
    if env_D:
        out += ["uniform sampler2D u_mir_D;", cubemap.GLSL]
    if lightmap:
        out += ["uniform sampler2D u_lightmap;", "uniform vec2 u_lm_repeat;"]
    out.append("void main() {")
    out += [f"    vec4 p_{k} = texture(u_params_{k}, v_uv);" for k in range(ntex)]
    out += ["    vec3 N = normalize(v_normal);", f"    vec3 rho_d = {rho_d};", "    vec3 L = vec3(0.0);"]
    if NP:
        out += [f"    for (int l = 0; l < {NP}; ++l) {{",
                "        vec3 d = u_point_pos[l] - v_pos;", "        float r2 = dot(d, d);",
                "        L += rho_d * u_point_power[l] / (u_point_falloff[l] > 0.5 ? r2 : 1.0) * "
                "max(dot(N, d * inversesqrt(r2)), 0.0);", "    }"]
    if ND:
        out += [f"    for (int l = 0; l < {ND}; ++l) L += rho_d * u_dir_power[l] * max(dot(N, u_dir_dir[l]), 0.0);"]
    if env_D:
        out.append(f"    L += rho_d * atlas_lod(u_mir_D, N, 0.0, {float(env_D)!r}, 0.0);  // the environment's D(N)")
    if lightmap:
        out.append("    L += rho_d * texture(u_lightmap, v_uv / u_lm_repeat).rgb;  // the light-mapped scene")
    out += ["    o_rad = vec4(L, 1.0);", "    o_pos = vec4(v_pos, 1.0);", "    o_nrm = vec4(N, 1.0);", "}"]
    return "\n".join(out) + "\n"


def fragment_code(effect, refl, material, exprs) -> tuple[str, list[str]]:
    """The reflector's specular lobes sampled from its mirror buffer (``u_mir<i>_*``, i its pass)."""
    from sbrdf_lib.lightmap import diffuse_glsl

    model = material.model
    kind = lobes.kind(model, "sampling")
    W, H = effect.scene.camera.resolution
    acc = ESTIMATORS[effect.estimator]
    u = f"u_mir{effect.reflectors.index(refl)}"
    env = effect.env
    if env is not None:  # a ray leaving the buffer sees the environment
        fallback = f"atlas_lod({u}_env, w, 0.0, {float(env.size)!r}, {float(np.log2(env.size))!r})"
        env_decls = f"uniform sampler2D {u}_env;\n{cubemap.GLSL}"
    else:
        fallback, env_decls = "vec3(0.0)", ""
    decls = [f"""
const float MIR_PI = 3.14159265358979;
const vec2 MIR_RES = vec2({float(W)!r}, {float(H)!r});
const float MIR_TOP = {float(np.log2(max(W, H)))!r};
{pattern_decls("MIR", "mir", effect)}
uniform sampler2D {u}_rad;
uniform sampler2D {u}_pos;
uniform sampler2D {u}_nrm;
uniform mat4 {u}_mvp;
{env_decls}
vec2 mir_uv(vec4 X) {{  // X.w = 0: a direction, projected to its vanishing point
    vec4 q = {u}_mvp * X;
    return q.w > 1e-9 ? q.xy / q.w * 0.5 + 0.5 : vec2(-1.0);
}}
vec2 mir_project(vec3 P, vec3 w) {{  // tangent plane at the mirror look-up, then {effect.refinements} refinement(s)
    vec2 uv = mir_uv(vec4(P, 1.0));
    for (int r = 0; r <= {effect.refinements}; ++r) {{
        vec4 pr = textureLod({u}_pos, uv, 0.0);
        vec4 X = vec4(w, 0.0);  // nothing there: the direction itself (the environment)
        if (pr.w > 0.5) {{
            vec3 nr = textureLod({u}_nrm, uv, 0.0).xyz;
            float d = dot(w, nr);
            float t = abs(d) > 1e-6 ? dot(pr.xyz - P, nr) / d : -1.0;
            if (t > 0.0) X = vec4(P + t * w, 1.0);
        }}
        uv = mir_uv(X);
        if (uv.x < 0.0) break;
    }}
    return uv;
}}
vec3 mir_fetch(vec2 uv, float lod, vec3 w) {{
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return {fallback};
    return textureLod({u}_rad, uv, lod).rgb;
}}
float mir_lod(vec3 P, vec3 e0, vec3 e1, vec3 e2, vec3 e3) {{  // ellipse through the lobe's extreme directions
    vec2 p0 = mir_project(P, e0), p1 = mir_project(P, e1), p2 = mir_project(P, e2), p3 = mir_project(P, e3);
    if (min(min(p0.x, p1.x), min(p2.x, p3.x)) < 0.0) return 0.0;  // an extreme direction behind the mirror camera
    float a = 0.5 * length((p0 - p2) * MIR_RES);
    float b = 0.5 * length((p1 - p3) * MIR_RES);
    return clamp(0.5 * log2(max(MIR_PI * a * b / float(MIR_K), 1e-30)), 0.0, MIR_TOP);
}}
vec3 mir_sample_cosine(vec3 rho, vec3 a, float n, vec3 N, vec3 P) {{
    float tt = acos(pow(MIR_XI_BORDER, 1.0 / (n + 1.0)));
    vec3 tu = normalize(cross(abs(a.z) < 0.9 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0), a));
    vec3 tv = cross(a, tu);
    float st = sin(tt), ct = cos(tt);
    float lod = mir_lod(P, st * tu + ct * a, st * tv + ct * a, -st * tu + ct * a, -st * tv + ct * a);
{cosine_ring_loop("MIR", "mir", acc, "mir_fetch(mir_project(P, w), lod, w)")}
}}
"""]
    body = ["    if (wo.z > 0.0) {  // planar reflector (sbrdf_envmap.mirror)"]
    if kind == "cosine":
        for rho, c, n, beta in lobes.glsl_cosine_lobes(model, exprs):
            body += ["        {", f"            vec3 pl = lobe_peak({c}, {beta}, wo);", "            float pn = length(pl);",
                     f"            if (pn > 0.0) L += mir_sample_cosine({rho} * exp(min({n} * log(pn), 60.0)), "
                     "(T * pl.x + B * pl.y + N * pl.z) / pn, " + n + ", N, v_pos);", "        }"]
        decls.insert(0, lobes.GLSL)
    elif kind == "beckmann":
        mx, my = lobes.glsl_slopes(model, exprs)
        call = model.glsl_call("wi", "wo", exprs)
        body += [f"""        {{
            float mx = {mx}, my = {my};
            float r = my / mx;
            int pat = r > MIR_LINE_THRESHOLD ? 1 : (r < 1.0 / MIR_LINE_THRESHOLD ? 2 : 0);
            vec3 ext[4];
            for (int e = 0; e < 4; ++e) {{
                float ph = float(e) * 0.5 * MIR_PI;
                float A = cos(ph) * cos(ph) / (mx * mx) + sin(ph) * sin(ph) / (my * my);
                float th = atan(sqrt(-log(MIR_XI_BORDER) / A));
                vec3 h = vec3(sin(th) * cos(ph), sin(th) * sin(ph), cos(th));
                vec3 wl = 2.0 * dot(wo, h) * h - wo;
                ext[e] = T * wl.x + B * wl.y + N * wl.z;
            }}
            float lod = mir_lod(v_pos, ext[0], ext[1], ext[2], ext[3]);
{beckmann_loop("MIR", acc, call, diffuse_glsl(exprs) or "vec3(0.0)", "mir_fetch(mir_project(v_pos, w), lod, w)")}
            L += mir_ratio(num, den);
        }}"""]
    body.append("    }")
    return "\n".join(decls) + "\n", body


def scene_pass(ctx, drawer, scene, skip: int, env_D: int, lightmap: bool, keep):
    """What a pass that draws the scene again needs (a mirror's reflection, a cube map's faces): one program per
    material (:func:`pass_fragment`, its lights and texture units set) and a vertex array per object but ``skip``.

    ``keep`` takes every GL object made (for release).  Returns ``(programs, [(material, vao, object index)])``.
    """
    points = [lt for lt in scene.lights if lt.type == "point"]
    dirs = [lt for lt in scene.lights if lt.type == "directional"]
    programs: dict = {}
    vaos = []
    for k, obj in enumerate(scene.objects):
        if k == skip:
            continue
        if obj.material not in programs:
            prog = keep(ctx.program(vertex_shader=PASS_VS, fragment_shader=pass_fragment(
                drawer.materials[obj.material], len(points), len(dirs), env_D, lightmap)))
            if points and "u_point_pos" in prog:
                prog["u_point_pos"].write(np.array([lt.vector for lt in points], "f4").tobytes())
                prog["u_point_power"].write(np.array([lt.power for lt in points], "f4").tobytes())
                prog["u_point_falloff"].write(np.array([float(lt.falloff) for lt in points], "f4").tobytes())
            if dirs and "u_dir_dir" in prog:
                prog["u_dir_dir"].write(np.array([lt.vector for lt in dirs], "f4").tobytes())
                prog["u_dir_power"].write(np.array([lt.power for lt in dirs], "f4").tobytes())
            for j, (uniform, _) in enumerate(drawer.textures[obj.material]):
                if uniform in prog:
                    prog[uniform].value = j
            for name in ("u_mir_D", "u_lightmap"):  # the unit after the material's own textures
                if name in prog:
                    prog[name].value = len(drawer.textures[obj.material])
            programs[obj.material] = prog
        mesh = drawer.meshes[k]
        vbo = keep(ctx.buffer(np.concatenate([mesh.positions, mesh.normals, mesh.uvs], 1).astype("f4").tobytes()))
        ibo = keep(ctx.buffer(mesh.indices.astype("u4").tobytes()))
        vaos.append((obj.material, keep(ctx.vertex_array(programs[obj.material],
                                                         [(vbo, "3f 3f 2f", "in_pos", "in_normal", "in_uv")], ibo)),
                     k))
    return programs, vaos


class MirrorPass:
    """One reflector's mirrored-camera buffer (radiance with a MIP chain, position, normal), redrawn every frame.

    Its textures are bound as ``u_mir<i>_rad``, ``_pos``, ``_nrm`` (and ``_env``, the environment's MIP
    chain, when the scene has one) for the reflector's material.
    """

    def __init__(self, effect, refl, i: int, drawer):
        import moderngl

        self.effect, self.refl, self.u, self.ctx = effect, refl, f"u_mir{i}", drawer.ctx
        ctx = self.ctx
        scene = effect.scene
        W, H = scene.camera.resolution
        self.res: list = []
        self.rad = self._keep(ctx.texture((W, H), 4, dtype="f4"))
        self.rad.build_mipmaps()
        self.rad.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.pos = self._keep(ctx.texture((W, H), 4, dtype="f4"))
        self.nrm = self._keep(ctx.texture((W, H), 4, dtype="f4"))
        for t in (self.pos, self.nrm):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        for t in (self.rad, self.pos, self.nrm):
            t.repeat_x = t.repeat_y = False
        self.fbo = self._keep(ctx.framebuffer(color_attachments=[self.rad, self.pos, self.nrm],
                                              depth_attachment=self._keep(ctx.depth_texture((W, H)))))
        env = effect.env
        self.env_tex = self.D_tex = None
        if env is not None:
            self.env_tex = self._atlas(env.levels, moderngl.LINEAR_MIPMAP_NEAREST)
            self.D_tex = self._atlas([env.map("D", env.diffuse_size)], moderngl.LINEAR)
        p0, n = refl.plane
        self.mvp = self._mvp(scene.camera)
        clip = np.append(n, -np.dot(n, p0)).astype("f4")
        self.programs, self.vaos = scene_pass(ctx, drawer, scene, refl.index,
                                              env.diffuse_size if env is not None else 0,
                                              bool(getattr(drawer, "lightmaps", None)), self._keep)
        for prog in self.programs.values():
            prog["u_mvp"].write(self.mvp.T.tobytes())
            prog["u_clip"].value = tuple(float(x) for x in clip)
        self.background = None
        if env is not None:
            prog = self._keep(ctx.program(vertex_shader=BACKGROUND_VS, fragment_shader=background_fragment(env.size)))
            prog["u_res"].value = (float(W), float(H))
            prog["u_plane_n"].value = tuple(float(x) for x in n)
            prog["u_mir_env"].value = 0
            tri = self._keep(ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], "f4").tobytes()))
            self.background = self._keep(ctx.vertex_array(prog, [(tri, "2f", "in_pos")]))
            self._background_camera(scene.camera)

    def _mvp(self, camera) -> np.ndarray:
        """The camera composed with the reflection about the plane (clip planes from the scene's bounds)."""
        scene = self.effect.scene
        p0, n = self.refl.plane
        reflect = np.eye(4)
        reflect[:3, :3] -= 2 * np.outer(n, n)
        reflect[:3, 3] = 2 * np.dot(n, p0) * n
        centre, radius = scene.bounds()
        dist = np.linalg.norm(camera.position - centre)
        far = dist + 3 * radius + 1e-6
        near = max(far * 1e-5, (dist - radius * 1.01) * 0.5)
        view, proj = camera.matrices(near, far)
        return (proj @ view @ reflect).astype("f4")

    def _background_camera(self, camera) -> None:
        W, H = camera.resolution
        right, up, forward = camera.basis()
        half = np.tan(np.radians(camera.fov_deg) / 2)
        assert self.background is not None, "called only where there is an environment, hence a background"
        prog = self.background.program
        prog["u_right"].value = tuple(float(x) for x in right * half * W / H)
        prog["u_up"].value = tuple(float(x) for x in up * half)
        prog["u_forward"].value = tuple(float(x) for x in forward)

    def set_camera(self, camera) -> None:
        """Follow a moved camera: the mirrored camera's matrices in every pass program."""
        self.mvp = self._mvp(camera)
        for prog in self.programs.values():
            prog["u_mvp"].write(self.mvp.T.tobytes())
        if self.background is not None:
            self._background_camera(camera)

    def _keep(self, obj):
        self.res.append(obj)
        return obj

    def _atlas(self, levels, min_filter):
        return self._keep(atlas_texture(self.ctx, levels, min_filter))

    def render(self, drawer) -> None:
        import moderngl

        ctx = self.ctx
        self.fbo.use()
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if self.background is not None:
            ctx.disable(moderngl.DEPTH_TEST)
            assert self.env_tex is not None, "a background is made only with an environment, with its texture"
            self.env_tex.use(0)
            self.background.render(moderngl.TRIANGLES)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.enable_direct(0x3000)  # GL_CLIP_DISTANCE0
        for name, vao, k in self.vaos:
            for j, (_, t) in enumerate(drawer.textures[name]):
                t.use(j)
            if getattr(drawer, "lightmaps", None):
                drawer.lightmaps[k].use(len(drawer.textures[name]))
                self.programs[name]["u_lm_repeat"].value = tuple(float(x) for x in drawer.scene.objects[k].uv_repeat)
            elif self.D_tex is not None:
                self.D_tex.use(len(drawer.textures[name]))
            vao.render(moderngl.TRIANGLES)
        ctx.disable_direct(0x3000)
        self.rad.build_mipmaps()

    def _bound(self) -> list:
        return [self.rad, self.pos, self.nrm] + ([self.env_tex] if self.env_tex is not None else [])

    def uniforms(self, prog, first: int) -> int:
        u = self.u
        if f"{u}_rad" in prog:
            for j, name in enumerate(("rad", "pos", "nrm", "env")[:len(self._bound())]):
                if f"{u}_{name}" in prog:
                    prog[f"{u}_{name}"].value = first + j
            prog[f"{u}_mvp"].write(self.mvp.T.tobytes())
        return len(self._bound())

    def use(self, first: int) -> int:
        bound = self._bound()
        for j, t in enumerate(bound):
            t.use(first + j)
        return len(bound)

    def release(self) -> None:
        for r in reversed(self.res):
            r.release()
        self.res = []
