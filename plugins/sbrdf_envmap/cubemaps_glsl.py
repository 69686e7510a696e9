"""GL side of the ``cubemaps`` effect: rendering each object's cube map and sampling it (Mühlbacher §4.4.1)."""

from __future__ import annotations

import numpy as np

from . import cubemap, lobes
from .glsl import ESTIMATORS, atlas_texture, beckmann_footprint_block, cosine_ring_loop, pattern_decls
from .mirror_glsl import BACKGROUND_VS, background_fragment, scene_pass


def _vec4_array(name: str, rows: np.ndarray) -> str:
    return f"const vec4 {name}[{len(rows)}] = vec4[](" + ", ".join(
        "vec4(" + ", ".join(repr(float(x)) for x in r) + ")" for r in rows) + ");"


def fragment_code(effect, target, material, exprs) -> tuple[str, list[str]]:
    """The object's specular lobes sampled from its cube map ``u_cub<i>``, parallax-corrected per sample."""
    from sbrdf_lib.lightmap import diffuse_glsl

    model = material.model
    kind = lobes.kind(model, "sampling")
    acc = ESTIMATORS[effect.estimator]
    i = effect.reflectors.index(target)
    S = float(target.size)
    top = float(np.log2(target.size))
    c = ", ".join(repr(float(x)) for x in target.centre)
    if target.parallax:
        planes = (f"const int CUB_NPLANES = {len(target.planes)};\n{_vec4_array('CUB_PLANES', target.planes)}\n"
                  "vec3 cub_dir(vec3 P, vec3 w) {  // Fig 4.5: from the centre to the nearest plane the ray hits\n"
                  "    float best = 1e30;\n"
                  "    for (int j = 0; j < CUB_NPLANES; ++j) {\n"
                  "        float dn = dot(CUB_PLANES[j].xyz, w);\n"
                  "        if (abs(dn) < 1e-8) continue;\n"
                  "        float t = (CUB_PLANES[j].w - dot(CUB_PLANES[j].xyz, P)) / dn;\n"
                  "        if (t > 0.0 && t < best) best = t;\n"
                  "    }\n"
                  "    return best < 1e30 ? P + best * w - CUB_C : w;\n"
                  "}")
    else:
        planes = "vec3 cub_dir(vec3 P, vec3 w) { return w; }  // the environment-at-infinity look-up"
    decls = [f"""
const float CUB_PI = 3.14159265358979;
const vec3 CUB_C = vec3({c});
{pattern_decls("CUB", "cub", effect)}
uniform samplerCube u_cub{i};
{cubemap.GLSL if effect.env is not None else ""}
{planes}
float cub_lod(float tu, float tv, vec3 d) {{  // Eqs 4.14-4.17 for the face size
    float amax = {float(sampling_max())!r};
    float area = CUB_PI * tan(min(tu, amax)) * tan(min(tv, amax)) / float(CUB_K);
    vec3 a = abs(normalize(d));
    float cb = max(max(a.x, a.y), a.z);
    float pixels = area / pow(max(cb, 1e-6), 3.0) * {S * S / 4!r};
    return clamp(0.5 * log2(max(pixels, 1e-30)), 0.0, {top!r});
}}
vec3 cub_fetch(vec3 P, vec3 w, float tu, float tv) {{
    vec3 d = cub_dir(P, w);
    return textureLod(u_cub{i}, d, cub_lod(tu, tv, d)).rgb;
}}
vec3 cub_sample_cosine(vec3 rho, vec3 a, float n, vec3 N, vec3 P) {{
    float tt = acos(pow(CUB_XI_BORDER, 1.0 / (n + 1.0)));
    vec3 tu = normalize(cross(abs(a.z) < 0.9 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0), a));
    vec3 tv = cross(a, tu);
{cosine_ring_loop("CUB", "cub", acc, "cub_fetch(P, w, tt, tt)")}
}}
"""]
    body = ["    if (wo.z > 0.0) {  // per-object cube map (sbrdf_envmap.cubemaps)"]
    if kind == "cosine":
        decls.insert(0, lobes.GLSL)
        for rho, cc, n, beta in lobes.glsl_cosine_lobes(model, exprs):
            body += ["        {", f"            vec3 pl = lobe_peak({cc}, {beta}, wo);", "            float pn = length(pl);",
                     f"            if (pn > 0.0) L += cub_sample_cosine({rho} * exp(min({n} * log(pn), 60.0)), "
                     "(T * pl.x + B * pl.y + N * pl.z) / pn, " + n + ", N, v_pos);", "        }"]
    elif kind == "beckmann":
        mx, my = lobes.glsl_slopes(model, exprs)
        call = model.glsl_call("wi", "wo", exprs)
        body.append(beckmann_footprint_block("CUB", acc, mx, my, call, diffuse_glsl(exprs) or "vec3(0.0)",
                                             "cub_fetch(v_pos, w, au, av)"))
    body.append("    }")
    return "\n".join(decls) + "\n", body


def sampling_max() -> float:
    from . import sampling

    return float(sampling.MAX_FOOTPRINT_ANGLE)


class CubePass:
    """One object's cube map: the diffuse scene without it, rendered once from its centre into a GL cube texture."""

    def __init__(self, effect, target, i: int, drawer):
        import moderngl

        from sbrdf_lib.scene import Camera

        from .cubemaps import FACES

        self.u, self.ctx = f"u_cub{i}", drawer.ctx
        ctx = self.ctx
        scene = effect.scene
        S = target.size
        env = effect.env
        lightmaps = getattr(drawer, "lightmaps", None) or []
        res: list = []

        def keep(o):
            res.append(o)
            return o

        colour = keep(ctx.texture((S, S), 4, dtype="f4"))
        fbo = keep(ctx.framebuffer(color_attachments=[colour, keep(ctx.texture((S, S), 4, dtype="f4")),
                                                      keep(ctx.texture((S, S), 4, dtype="f4"))],
                                   depth_attachment=keep(ctx.depth_texture((S, S)))))
        D_tex = env_tex = None
        if env is not None:
            env_tex = keep(atlas_texture(ctx, env.levels, moderngl.LINEAR_MIPMAP_NEAREST))
            D_tex = keep(atlas_texture(ctx, [env.map("D", env.diffuse_size)], moderngl.LINEAR))
        programs, vaos = scene_pass(ctx, drawer, scene, target.index, env.diffuse_size if env is not None else 0,
                                    bool(lightmaps), keep)
        background = None
        if env is not None:
            bg = keep(ctx.program(vertex_shader=BACKGROUND_VS, fragment_shader=background_fragment(env.size)))
            bg["u_res"].value = (float(S), float(S))
            bg["u_plane_n"].value = (0.0, 0.0, 0.0)  # no reflection: the camera's own ray
            bg["u_mir_env"].value = 0
            tri = keep(ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], "f4").tobytes()))
            background = keep(ctx.vertex_array(bg, [(tri, "2f", "in_pos")]))
        centre, radius = scene.bounds()
        far = float(np.linalg.norm(target.centre - centre) + 2 * radius) * 1.01
        near = max(far * 1e-5, 1e-4)
        self.cube = ctx.texture_cube((S, S), 4, dtype="f4")
        for f, (fwd, up) in enumerate(FACES):
            cam = Camera(target.centre, target.centre + np.asarray(fwd, float), np.asarray(up, float), 90.0, (S, S))
            view, proj = cam.matrices(near, far)
            mvp = (proj @ view).astype("f4")
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            if background is not None:
                right, upv, forward = cam.basis()
                background.program["u_right"].value = tuple(float(x) for x in right)
                background.program["u_up"].value = tuple(float(x) for x in upv)
                background.program["u_forward"].value = tuple(float(x) for x in forward)
                ctx.disable(moderngl.DEPTH_TEST)
                assert env_tex is not None, "a background is made only with an environment, with its texture"
                env_tex.use(0)
                background.render(moderngl.TRIANGLES)
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.disable(moderngl.CULL_FACE)
            for name, vao, k in vaos:
                prog = programs[name]
                prog["u_mvp"].write(mvp.T.tobytes())
                for j, (_, t) in enumerate(drawer.textures[name]):
                    t.use(j)
                if lightmaps:
                    lightmaps[k].use(len(drawer.textures[name]))
                    if "u_lm_repeat" in prog:
                        prog["u_lm_repeat"].value = tuple(float(x) for x in scene.objects[k].uv_repeat)
                elif D_tex is not None:
                    D_tex.use(len(drawer.textures[name]))
                vao.render(moderngl.TRIANGLES)
            ctx.finish()
            self.cube.write(f, colour.read())  # GL rows bottom-up = the face's t upwards, as a cube face stores it
        self.cube.build_mipmaps()
        self.cube.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        for r in reversed(res):
            r.release()

    def uniforms(self, prog, first: int) -> int:
        if self.u in prog:
            prog[self.u].value = first
        return 1

    def use(self, first: int) -> int:
        self.cube.use(first)
        return 1

    def render(self, drawer) -> None:  # static: rendered once
        pass

    def set_camera(self, camera) -> None:
        pass

    def release(self) -> None:
        if self.cube is not None:
            self.cube.release()
            self.cube = None
