"""GLSL and GL textures of the ``environment`` effect: the same formulas as the NumPy paths in :mod:`.effect`.

Cube maps are atlas textures (:mod:`.cubemap`); the pattern of the
deterministic mode is compiled in as constants (the sample count is a
compile-time constant, so the loop unrolls); the progressive mode receives
each frame's block of Sobol points as a uniform and blends the frame into
its own copy of the previous image (weight 1/(k+1) on frame k).
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError

from . import cubemap, lobes, prefilter, sampling

#: Numerator and denominator terms of Eqs 4.23, 4.24, 4.25 (see sampling.estimate).
ESTIMATORS = {"4.23": ("Li * f * c", "vec3(p)"), "4.24": ("Li * f * c * c", "vec3(p * c)"),
              "4.25": ("Li * f * f / p * c * c", "f * c")}

COMMON = """
const float ENV_PI = 3.14159265358979;
"""


def _vec2_array(name: str, pts: np.ndarray) -> str:
    return f"const vec2 {name}[{len(pts)}] = vec2[](" + ", ".join(f"vec2({float(a)!r}, {float(b)!r})" for a, b in pts) + ");"


def pattern_decls(P: str, p: str, effect) -> str:
    """Constants of the deterministic patterns (ring, two lines) and the ratio of Eq 4.25, under prefix ``P``/``p``.

    The environment (``ENV``/``env``) and the planar mirror (``MIR``/``mir``) sample lobes the same way and
    differ only in where L_i comes from (:func:`cosine_ring_loop`, :func:`beckmann_loop`).
    """
    K = effect.samples
    return "\n".join([
        f"const int {P}_K = {K};", f"const float {P}_XI_BORDER = {effect.xi_border!r};",
        f"const float {P}_LINE_THRESHOLD = {effect.line_threshold!r};",
        _vec2_array(f"{P}_RING", sampling.pattern("ring", K, effect.ring_radius)),
        _vec2_array(f"{P}_LINE_B", sampling.pattern("line-b", K, effect.ring_radius)),
        _vec2_array(f"{P}_LINE_T", sampling.pattern("line-t", K, effect.ring_radius)),
        f"vec3 {p}_ratio(vec3 num, vec3 den) {{",
        "    return vec3(den.x > 0.0 ? num.x / den.x : 0.0, den.y > 0.0 ? num.y / den.y : 0.0, "
        "den.z > 0.0 ? num.z / den.z : 0.0);",
        "}",
    ])


def cosine_ring_loop(P: str, p: str, acc: tuple[str, str], lookup: str) -> str:
    """The ring about a cosine lobe's peak ``a`` (tangents ``tu``, ``tv``, half-angle ``tt``, exponent ``n``):
    Eq 4.25's sums and their ratio.  ``lookup`` is L_i at the world direction ``w``."""
    return f"""    vec3 num = vec3(0.0), den = vec3(0.0);
    for (int k = 0; k < {P}_K; ++k) {{
        float th = (1.0 - {P}_RING[k].x) * tt, ph = 2.0 * {P}_PI * {P}_RING[k].y;
        vec3 w = sin(th) * (cos(ph) * tu + sin(ph) * tv) + cos(th) * a;
        float c = dot(w, N);
        if (c <= 0.0) continue;  // below the horizon: dropped from both sums
        float g = pow(max(cos(th), 0.0), n);
        vec3 f = rho * g;
        float p = (n + 1.0) / (2.0 * {P}_PI) * g;
        vec3 Li = {lookup};
        num += {acc[0]}; den += {acc[1]};
    }}
    return {p}_ratio(num, den);"""


def beckmann_loop(P: str, acc: tuple[str, str], call: str, rho_d: str, lookup: str) -> str:
    """Eq 4.25's sums over a Beckmann lobe's pattern (``pat``, slopes ``mx``, ``my``; Mühlbacher §4.4.3).
    ``lookup`` is L_i at the world direction ``w``."""
    return f"""            vec3 num = vec3(0.0), den = vec3(0.0);
            for (int k = 0; k < {P}_K; ++k) {{
                vec2 xi = pat == 1 ? {P}_LINE_B[k] : (pat == 2 ? {P}_LINE_T[k] : {P}_RING[k]);
                float ph = atan(my * sin(2.0 * {P}_PI * xi.y), mx * cos(2.0 * {P}_PI * xi.y));
                float A = cos(ph) * cos(ph) / (mx * mx) + sin(ph) * sin(ph) / (my * my);
                float th = (1.0 - xi.x) * atan(sqrt(-log({P}_XI_BORDER) / A));
                vec3 h = vec3(sin(th) * cos(ph), sin(th) * sin(ph), cos(th));
                float oh = dot(wo, h);
                vec3 wi = 2.0 * oh * h - wo;
                if (oh <= 0.0 || wi.z <= 0.0) continue;
                float c = wi.z;
                vec3 f = {call} - {rho_d};
                float cth = cos(th);
                float p = exp(-tan(th) * tan(th) * A) / (4.0 * {P}_PI * mx * my * cth * cth * cth * oh);
                vec3 w = T * wi.x + B * wi.y + N * wi.z;
                vec3 Li = {lookup};
                num += {acc[0]}; den += {acc[1]};
            }}"""


def _textures(effect) -> list[tuple[str, str, int]]:
    """(uniform name, map key, face size) of the atlases a method reads."""
    m = effect.method
    out = [] if m == "progressive" and not getattr(effect, "reflectors", None) else [("u_env_D", "D", effect.diffuse_size)]
    if m == "prefiltered-discrete":
        out += [(f"u_env_S{k}", f"S{e:g}", effect.prefiltered_size) for k, e in enumerate(prefilter.EXPONENTS)]
    elif m == "prefiltered-mip":
        out.append(("u_env_M", "mip", effect.prefiltered_size))
    if m in ("sampling", "progressive"):
        out.append(("u_env_src", "levels", effect.size))
    return out


def fragment_code(effect, material, exprs: dict) -> tuple[str, list[str]]:
    if effect.method == "mc":
        raise SbrdfError("environment method 'mc' is the cpu renderer's reference; the gl renderer converges to it "
                         "with method: progressive (frames: N)")
    model = material.model
    kind = lobes.kind(model, effect.method) if effect.method != "progressive" else None
    decls = [COMMON, cubemap.GLSL, lobes.GLSL]
    decls += [f"uniform sampler2D {u};" for u, _, _ in _textures(effect)]
    body = ["    if (wo.z > 0.0) {  // environment lighting (sbrdf_envmap)"]
    size_D, size_S, size = (float(effect.diffuse_size), float(effect.prefiltered_size), float(effect.size))
    top = float(np.log2(effect.size))
    if effect.method != "progressive" and not getattr(effect, "lightmapped", False):  # else: the light map's
        body.append(f"        L += {exprs['rho_d']} * atlas_lod(u_env_D, N, 0.0, {size_D!r}, 0.0);")
    if effect.method.startswith("prefiltered"):
        if effect.method == "prefiltered-discrete":
            fetch = "\n".join(f"    w = max(0.0, 1.0 - abs(t - {k}.0)); if (w > 0.0) s += w * "
                              f"atlas_lod(u_env_S{k}, d, 0.0, {size_S!r}, 0.0);" for k in range(len(prefilter.EXPONENTS)))
            decls.append("vec3 env_specular(vec3 d, float n) {  // hat-function blend in log4 n\n"
                         "    float t = clamp(log(max(n, 1e-30)) / log(4.0), 0.0, 4.0), w;\n    vec3 s = vec3(0.0);\n"
                         f"{fetch}\n    return s;\n}}")
        else:
            decls.append("vec3 env_specular(vec3 d, float n) {  // level = log4(256 / n)\n"
                         "    float t = clamp(log(max(n, 1e-30)) / log(4.0), 0.0, 4.0);\n"
                         f"    return atlas_lod(u_env_M, d, 4.0 - t, {size_S!r}, 4.0);\n}}")
        cos = "max(pl.z / pn, 0.0)" if effect.cosine == "normalized" else "max(pl.z, 0.0)"
        for rho, c, n, beta in lobes.glsl_cosine_lobes(model, exprs) if kind == "cosine" else []:
            body += ["        {",
                     f"            vec3 pl = lobe_peak({c}, {beta}, wo);",
                     "            float pn = length(pl);",
                     "            if (pn > 0.0) {",
                     f"                float n = {n};",
                     "                vec3 d = (T * pl.x + B * pl.y + N * pl.z) / pn;",
                     f"                L += {rho} * exp(min(n * log(pn), 60.0)) * env_specular(d, n) * {cos};",
                     "            }", "        }"]
    elif effect.method == "sampling":
        decls += _sampling_decls(effect, size, top)
        if kind == "cosine":
            for rho, c, n, beta in lobes.glsl_cosine_lobes(model, exprs):
                body += ["        {",
                         f"            vec3 pl = lobe_peak({c}, {beta}, wo);",
                         "            float pn = length(pl);",
                         f"            if (pn > 0.0) L += env_sample_cosine({rho} * exp(min({n} * log(pn), 60.0)), "
                         f"(T * pl.x + B * pl.y + N * pl.z) / pn, {n}, N);",
                         "        }"]
        elif kind == "beckmann":
            mx, my = lobes.glsl_slopes(model, exprs)
            call = model.glsl_call("wi", "wo", exprs)
            body += _beckmann_block(effect, mx, my, call, exprs["rho_d"])
    else:  # progressive
        decls += _progressive_decls(effect) + [BECKMANN_PDF]
        body += _progressive_block(effect, model, exprs)
    body.append("    }")
    if effect.method == "progressive":
        body += PROGRESSIVE_TAIL
    return "\n".join(decls) + "\n", body


def _sampling_decls(effect, size: float, top: float) -> list[str]:
    acc = ESTIMATORS[effect.estimator]
    lines = [pattern_decls("ENV", "env", effect), f"""
float env_lod(float tu, float tv, vec3 d) {{  // Eqs 4.14-4.17
    float amax = {float(sampling.MAX_FOOTPRINT_ANGLE)!r};
    float area = ENV_PI * tan(min(tu, amax)) * tan(min(tv, amax)) / float(ENV_K);
    vec3 a = abs(d);
    float cb = max(max(a.x, a.y), a.z);
    float pixels = area / pow(max(cb, 1e-6), 3.0) * {size * size / 4!r};
    return clamp(0.5 * log2(max(pixels, 1e-30)), 0.0, {top!r});
}}
vec3 env_sample_cosine(vec3 rho, vec3 a, float n, vec3 N) {{  // ring about the peak
    float tt = acos(pow(ENV_XI_BORDER, 1.0 / (n + 1.0)));
    vec3 tu = normalize(cross(abs(a.z) < 0.9 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0), a));
    vec3 tv = cross(a, tu);
{cosine_ring_loop("ENV", "env", acc, f"atlas_lod(u_env_src, w, env_lod(tt, tt, w), {size!r}, {top!r})")}
}}
"""]
    return lines


def beckmann_footprint_block(P: str, acc: tuple[str, str], mx: str, my: str, call: str, rho_d: str,
                             lookup: str) -> str:
    """A Beckmann lobe's whole block: its pattern from the slopes' ratio, the angles ``au``, ``av`` its border
    spans along the two axes (for the look-up's MIP level), :func:`beckmann_loop`, and the estimator's ratio
    (``<p>_ratio``).  Shared by the environment map (``ENV``) and the per-object cube maps (``CUB``)."""
    return f"""        {{
            float mx = {mx}, my = {my};
            float r = my / mx;
            int pat = r > {P}_LINE_THRESHOLD ? 1 : (r < 1.0 / {P}_LINE_THRESHOLD ? 2 : 0);
            float lx = sqrt(-log({P}_XI_BORDER));
            vec3 wc = vec3(-wo.x, -wo.y, wo.z);
            float tu = atan(lx * mx), tv = atan(lx * my);
            vec3 hu = vec3(sin(tu), 0.0, cos(tu)), hv = vec3(0.0, sin(tv), cos(tv));
            vec3 wu = 2.0 * dot(wo, hu) * hu - wo, wv = 2.0 * dot(wo, hv) * hv - wo;
            float au = acos(clamp(dot(wc, wu), -1.0, 1.0)), av = acos(clamp(dot(wc, wv), -1.0, 1.0));
{beckmann_loop(P, acc, call, rho_d, lookup)}
            L += {P.lower()}_ratio(num, den);
        }}"""


def _beckmann_block(effect, mx: str, my: str, call: str, rho_d: str) -> list[str]:
    size, top = float(effect.size), float(np.log2(effect.size))
    lookup = f"atlas_lod(u_env_src, w, env_lod(au, av, w), {size!r}, {top!r})"
    return beckmann_footprint_block("ENV", ESTIMATORS[effect.estimator], mx, my, call, rho_d, lookup).split("\n")


def _progressive_decls(effect) -> list[str]:
    K = effect.mc_samples
    return [f"const int ENV_MC = {K};", f"uniform vec2 u_env_xi[{K}];", "uniform sampler2D u_env_accum;",
            "uniform float u_env_weight;", """
vec2 env_rotation(int j) {  // per-pixel Cranley-Patterson rotation of strategy j
    vec2 q = gl_FragCoord.xy + vec2(float(j) * 17.0, float(j) * 31.0);
    return fract(vec2(dot(q, vec2(0.7548776662, 0.5698402909)), dot(q, vec2(0.5698402909, 0.3247179572))) + 0.5);
}
"""]


def _progressive_block(effect, model, exprs) -> list[str]:
    """One frame's MIS estimate (cosine hemisphere + each lobe's sampler), blended into the running mean."""
    try:
        kind = lobes.kind(model, "mc")
    except SbrdfError:
        kind = "other"
    call = model.glsl_call("wi", "wo", exprs)
    if getattr(effect, "lightmapped", False):  # the diffuse part is the light map's
        call = f"({call} - {exprs['rho_d']})"
    strategies: list[tuple[str, int]] = [("hemisphere", 0)]  # (sampler, lobe)
    setup: list[str] = []
    if kind == "cosine":
        for j, (_rho, c, n, beta) in enumerate(lobes.glsl_cosine_lobes(model, exprs)):
            setup += [f"            vec3 pa{j} = lobe_peak({c}, {beta}, wo); pa{j} /= max(length(pa{j}), 1e-30);",
                      f"            float pe{j} = {n};",
                      f"            vec3 pu{j} = normalize(cross(abs(pa{j}.z) < 0.9 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0), pa{j}));",
                      f"            vec3 pv{j} = cross(pa{j}, pu{j});"]
            strategies.append(("cosine", j))
    elif kind == "beckmann":
        mx, my = lobes.glsl_slopes(model, exprs)
        setup.append(f"            float bmx = {mx}, bmy = {my};")
        strategies.append(("beckmann", 0))
    # pdf of every strategy at wi (balance heuristic)
    pdf = ["max(wi.z, 0.0) / ENV_PI"]
    for strategy, j in strategies[1:]:
        if strategy == "cosine":
            pdf.append(f"(pe{j} + 1.0) / (2.0 * ENV_PI) * pow(max(dot(wi, pa{j}), 0.0), pe{j})")
        else:
            pdf.append("env_beckmann_pdf(wi, wo, bmx, bmy)")
    gen = []
    for j, (strategy, i) in enumerate(strategies):
        u = f"fract(u_env_xi[k] + env_rotation({j}))"
        if strategy == "hemisphere":
            g = (f"vec2 u = {u}; float r = sqrt(u.x), ph = 2.0 * ENV_PI * u.y; "
                 "wi = vec3(r * cos(ph), r * sin(ph), sqrt(max(1.0 - u.x, 0.0)));")
        elif strategy == "cosine":
            g = (f"vec2 u = clamp({u}, 1e-7, 1.0 - 1e-7); float ct = pow(u.x, 1.0 / (pe{i} + 1.0)), "
                 f"st = sqrt(max(1.0 - ct * ct, 0.0)), ph = 2.0 * ENV_PI * u.y; "
                 f"wi = st * (cos(ph) * pu{i} + sin(ph) * pv{i}) + ct * pa{i};")
        else:
            g = (f"vec2 u = clamp({u}, 1e-7, 1.0 - 1e-7); float ph = atan(bmy * sin(2.0 * ENV_PI * u.y), "
                 "bmx * cos(2.0 * ENV_PI * u.y)); float A = cos(ph) * cos(ph) / (bmx * bmx) + sin(ph) * sin(ph) / "
                 "(bmy * bmy); float th = atan(sqrt(-log(1.0 - u.x) / A)); "
                 "vec3 h = vec3(sin(th) * cos(ph), sin(th) * sin(ph), cos(th)); wi = 2.0 * dot(wo, h) * h - wo;")
        gen.append(g)
    lines = ["        {", "            vec3 Lenv = vec3(0.0);"] + setup
    for g in gen:
        lines += ["            for (int k = 0; k < ENV_MC; ++k) {", "                vec3 wi;", f"                {{ {g} }}",
                  "                if (wi.z <= 0.0) continue;",
                  f"                float pdf = {' + '.join(pdf)};",
                  "                if (pdf <= 0.0) continue;",
                  "                vec3 w = T * wi.x + B * wi.y + N * wi.z;",
                  f"                Lenv += {call} * atlas_lod(u_env_src, w, 0.0, {float(effect.size)!r}, 0.0) * wi.z "
                  f"/ (pdf * float(ENV_MC));",
                  "            }"]
    lines += ["            L += Lenv;", "        }"]
    return lines


PROGRESSIVE_TAIL = ["    L = mix(texelFetch(u_env_accum, ivec2(gl_FragCoord.xy), 0).rgb, L, u_env_weight);  // running mean"]

BECKMANN_PDF = """
float env_beckmann_pdf(vec3 wi, vec3 wo, float mx, float my) {  // Eq 4.9 for any wi
    vec3 h = normalize(wi + wo);
    float oh = dot(wo, h);
    if (h.z <= 1e-9 || oh <= 0.0) return 0.0;
    float e = (h.x * h.x / (mx * mx) + h.y * h.y / (my * my)) / (h.z * h.z);
    return exp(-e) / (4.0 * ENV_PI * mx * my * h.z * h.z * h.z * oh);
}
"""


def atlas_texture(ctx, levels, min_filter):
    """A cube map's levels as one atlas texture (:func:`cubemap.atlas`), level L in mip level L, clamped."""
    import moderngl

    imgs = cubemap.atlas(levels)
    tex = ctx.texture((imgs[0].shape[1], imgs[0].shape[0]), 3, imgs[0].tobytes(), dtype="f4")
    if len(imgs) > 1:
        tex.build_mipmaps()
        for L, img in enumerate(imgs[1:], 1):
            tex.write(img.tobytes(), level=L)
    tex.filter = (min_filter, moderngl.LINEAR)
    tex.repeat_x = tex.repeat_y = False
    return tex


class GLResources:
    """The atlases a method reads, uploaded once; the progressive mode's accumulation copy."""

    def __init__(self, effect, ctx):
        import moderngl

        self.effect, self.ctx = effect, ctx
        self.textures = []
        for uniform, key, size in _textures(effect):
            if key == "levels":
                levels = effect.levels
            elif key == "mip":
                levels = effect.mip
            else:
                levels = [effect.map(key, size)]
            tex = atlas_texture(ctx, levels, moderngl.LINEAR_MIPMAP_NEAREST if len(levels) > 1 else moderngl.LINEAR)
            self.textures.append((uniform, tex))
        self.accum = None

    def uniforms(self, prog, first: int) -> int:
        unit = first
        for uniform, _ in self.textures:
            if uniform in prog:
                prog[uniform].value = unit
            unit += 1
        if self.effect.method == "progressive":
            if "u_env_accum" in prog:  # not in a reflector's program (diffuse only)
                prog["u_env_accum"].value = unit
            unit += 1
        return unit - first

    def use(self, first: int) -> int:
        """Bind the textures from unit ``first`` on; returns how many units they take."""
        unit = first
        for _, tex in self.textures:
            tex.use(unit)
            unit += 1
        if self.effect.method == "progressive":
            if self.accum is not None:
                self.accum.use(unit)
            unit += 1
        return unit - first

    def frame(self, drawer, k: int) -> None:
        """Frame k of the progressive mode: its Sobol block, the weight 1/(k+1), a copy of frame k−1."""
        eff = self.effect
        pts = sampling.sobol_points(eff.mc_samples, eff.mc_samples * k, eff.seed, 0).astype("f4")
        W, H = drawer.scene.camera.resolution
        if self.accum is None:
            self.accum = self.ctx.texture((W, H), 4, dtype="f4")
        if k > 0:  # through memory: llvmpipe's framebuffer copy clamps float colour to [0, 1]
            self.accum.write(drawer.fbo.read(components=4, dtype="f4"))
        for prog in drawer.programs.values():
            if "u_env_xi" in prog:
                prog["u_env_xi"].write(pts.tobytes())
                prog["u_env_weight"].value = 1.0 / (k + 1)

    def release(self) -> None:
        for _, tex in self.textures:
            tex.release()
        if self.accum is not None:
            self.accum.release()
        self.textures, self.accum = [], None
