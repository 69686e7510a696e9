"""GL side of the ``mirror`` effect: the mirrored-camera pass and the reflector's sampling code (Mühlbacher §4.5)."""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError

from . import lobes
from .glsl import ESTIMATORS, beckmann_loop, cosine_ring_loop, pattern_decls

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


def pass_fragment(material, NP: int, ND: int) -> str:
    """Diffuse-only radiance, world position and normal of the mirrored view (three colour attachments)."""
    from sbrdf_lib.gl import parameter_exprs

    ntex, exprs = parameter_exprs(material.model, "p")
    if "rho_d" not in exprs:
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
    out.append("void main() {")
    out += [f"    vec4 p_{k} = texture(u_params_{k}, v_uv);" for k in range(ntex)]
    out += ["    vec3 N = normalize(v_normal);", f"    vec3 rho_d = {exprs['rho_d']};", "    vec3 L = vec3(0.0);"]
    if NP:
        out += [f"    for (int l = 0; l < {NP}; ++l) {{",
                "        vec3 d = u_point_pos[l] - v_pos;", "        float r2 = dot(d, d);",
                "        L += rho_d * u_point_power[l] / (u_point_falloff[l] > 0.5 ? r2 : 1.0) * "
                "max(dot(N, d * inversesqrt(r2)), 0.0);", "    }"]
    if ND:
        out += [f"    for (int l = 0; l < {ND}; ++l) L += rho_d * u_dir_power[l] * max(dot(N, u_dir_dir[l]), 0.0);"]
    out += ["    o_rad = vec4(L, 1.0);", "    o_pos = vec4(v_pos, 1.0);", "    o_nrm = vec4(N, 1.0);", "}"]
    return "\n".join(out) + "\n"


def fragment_code(effect, material, exprs) -> tuple[str, list[str]]:
    model = material.model
    kind = lobes.kind(model, "sampling")
    W, H = effect.scene.camera.resolution
    acc = ESTIMATORS[effect.estimator]
    decls = [f"""
const float MIR_PI = 3.14159265358979;
const vec2 MIR_RES = vec2({float(W)!r}, {float(H)!r});
const float MIR_TOP = {float(np.log2(max(W, H)))!r};
const float MIR_FAR = {effect.far!r};
{pattern_decls("MIR", "mir", effect)}
uniform sampler2D u_mir_rad;
uniform sampler2D u_mir_pos;
uniform sampler2D u_mir_nrm;
uniform mat4 u_mir_mvp;
vec2 mir_uv(vec3 X) {{ vec4 q = u_mir_mvp * vec4(X, 1.0); return q.xy / q.w * 0.5 + 0.5; }}
vec2 mir_project(vec3 P, vec3 w) {{  // tangent plane at the mirror look-up, then {effect.refinements} refinement(s)
    vec2 uv = mir_uv(P);
    for (int r = 0; r <= {effect.refinements}; ++r) {{
        vec4 pr = textureLod(u_mir_pos, uv, 0.0);
        vec3 X = P + w * MIR_FAR;  // nothing there: a point far along the ray
        if (pr.w > 0.5) {{
            vec3 nr = textureLod(u_mir_nrm, uv, 0.0).xyz;
            float d = dot(w, nr);
            float t = abs(d) > 1e-6 ? dot(pr.xyz - P, nr) / d : -1.0;
            if (t > 0.0) X = P + t * w;
        }}
        uv = mir_uv(X);
    }}
    return uv;
}}
vec3 mir_fetch(vec2 uv, float lod) {{
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return vec3(0.0);
    return textureLod(u_mir_rad, uv, lod).rgb;
}}
float mir_lod(vec3 P, vec3 e0, vec3 e1, vec3 e2, vec3 e3) {{  // ellipse through the lobe's extreme directions
    float a = 0.5 * length((mir_project(P, e0) - mir_project(P, e2)) * MIR_RES);
    float b = 0.5 * length((mir_project(P, e1) - mir_project(P, e3)) * MIR_RES);
    return clamp(0.5 * log2(max(MIR_PI * a * b / float(MIR_K), 1e-30)), 0.0, MIR_TOP);
}}
vec3 mir_sample_cosine(vec3 rho, vec3 a, float n, vec3 N, vec3 P) {{
    float tt = acos(pow(MIR_XI_BORDER, 1.0 / (n + 1.0)));
    vec3 tu = normalize(cross(abs(a.z) < 0.9 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0), a));
    vec3 tv = cross(a, tu);
    float st = sin(tt), ct = cos(tt);
    float lod = mir_lod(P, st * tu + ct * a, st * tv + ct * a, -st * tu + ct * a, -st * tv + ct * a);
{cosine_ring_loop("MIR", "mir", acc, "mir_fetch(mir_project(P, w), lod)")}
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
{beckmann_loop("MIR", acc, call, exprs['rho_d'], "mir_fetch(mir_project(v_pos, w), lod)")}
            L += mir_ratio(num, den);
        }}"""]
    body.append("    }")
    return "\n".join(decls) + "\n", body


class MirrorPass:
    """The mirrored-camera buffer (radiance with a MIP chain, position, normal), redrawn every frame."""

    def __init__(self, effect, drawer):
        import moderngl

        self.effect, self.ctx = effect, drawer.ctx
        ctx = self.ctx
        scene = effect.scene
        W, H = scene.camera.resolution
        self.res = []
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
        # camera: the renderer's, composed with the reflection about the plane
        p0, n = effect.plane
        refl = np.eye(4)
        refl[:3, :3] -= 2 * np.outer(n, n)
        refl[:3, 3] = 2 * np.dot(n, p0) * n
        centre, radius = scene.bounds()
        dist = np.linalg.norm(scene.camera.position - centre)
        far = dist + 3 * radius + 1e-6
        near = max(far * 1e-5, (dist - radius * 1.01) * 0.5)
        view, proj = scene.camera.matrices(near, far)
        self.mvp = (proj @ view @ refl).astype("f4")
        clip = np.append(n, -np.dot(n, p0)).astype("f4")
        points = [lt for lt in scene.lights if lt.type == "point"]
        dirs = [lt for lt in scene.lights if lt.type == "directional"]
        self.programs, self.vaos = {}, []
        for k, obj in enumerate(scene.objects):
            if k == effect.index:
                continue
            m = drawer.materials[obj.material]
            if obj.material not in self.programs:
                prog = self._keep(ctx.program(vertex_shader=PASS_VS, fragment_shader=pass_fragment(m, len(points), len(dirs))))
                prog["u_mvp"].write(self.mvp.T.tobytes())
                prog["u_clip"].value = tuple(float(x) for x in clip)
                if points:
                    prog["u_point_pos"].write(np.array([lt.vector for lt in points], "f4").tobytes())
                    prog["u_point_power"].write(np.array([lt.power for lt in points], "f4").tobytes())
                    prog["u_point_falloff"].write(np.array([float(lt.falloff) for lt in points], "f4").tobytes())
                if dirs:
                    prog["u_dir_dir"].write(np.array([lt.vector for lt in dirs], "f4").tobytes())
                    prog["u_dir_power"].write(np.array([lt.power for lt in dirs], "f4").tobytes())
                for j, (uniform, _) in enumerate(drawer.textures[obj.material]):
                    if uniform in prog:
                        prog[uniform].value = j
                self.programs[obj.material] = prog
            mesh = drawer.meshes[k]
            vbo = self._keep(ctx.buffer(np.concatenate([mesh.positions, mesh.normals, mesh.uvs], 1).astype("f4").tobytes()))
            ibo = self._keep(ctx.buffer(mesh.indices.astype("u4").tobytes()))
            vao = self._keep(ctx.vertex_array(self.programs[obj.material],
                                              [(vbo, "3f 3f 2f", "in_pos", "in_normal", "in_uv")], ibo))
            self.vaos.append((obj.material, vao))

    def _keep(self, obj):
        self.res.append(obj)
        return obj

    def render(self, drawer) -> None:
        import moderngl

        ctx = self.ctx
        self.fbo.use()
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.enable_direct(0x3000)  # GL_CLIP_DISTANCE0
        for name, vao in self.vaos:
            for j, (_, t) in enumerate(drawer.textures[name]):
                t.use(j)
            vao.render(moderngl.TRIANGLES)
        ctx.disable_direct(0x3000)
        self.rad.build_mipmaps()

    def uniforms(self, prog, first: int) -> int:
        if "u_mir_rad" in prog:
            prog["u_mir_rad"].value = first
            prog["u_mir_pos"].value = first + 1
            prog["u_mir_nrm"].value = first + 2
            prog["u_mir_mvp"].write(self.mvp.T.tobytes())
        return 3

    def use(self, first: int) -> int:
        for j, t in enumerate((self.rad, self.pos, self.nrm)):
            t.use(first + j)
        return 3

    def release(self) -> None:
        for r in reversed(self.res):
            r.release()
        self.res = []
