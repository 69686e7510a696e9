"""McAllister's prefiltered environment maps (seed 000 §6.9, Eqs 6.14, 6.17).

    D(N)      = ∫ (N·ω_i)⁺ L_i(ω_i) dω_i          the diffuse (irradiance) map
    S(ω_p, n) = ∫ ((ω̂_p·ω_i)⁺)^n L_i(ω_i) dω_i     the specular map of exponent n

D is S with n = 1.  The convolution method is not given in the text; here
it is the brute-force sum over the source cube's texels,

    S(ω_p, n) = Σ_t max(0, ω̂_p·ω_t)^n L(ω_t) Δω_t,

with Δω_t each texel's exact solid angle (the notes' midpoint form
(2/S)²/(1 + a² + b²)^{3/2} is 0.4 % off in total at S = 8),

in float64 NumPy (:func:`prefilter_numpy`, the reference integrator) or as a
GL fragment pass (:func:`prefilter_gl`) computing the same sum per output
texel.  One set of maps serves every texel, lobe and object: the BRDF enters
only through the look-up direction p = C·ω_r and the exponent.

The two representations of S (§6.2 of the notes):

- ``discrete``: one cube per exponent in :data:`EXPONENTS` (1, 4, 16, 64, 256),
  all at the same size, blended per pixel with hat-function weights in
  t = log₄ n (see :func:`discrete_weights`).
- ``mip``: one MIP-mapped cube whose level L holds n = 256/4^L at size S/2^L
  (McAllister's suggestion: resolution falls with bandwidth); the look-up
  level is log₄(256/n), the same t, so both forms interpolate identically.
"""

from __future__ import annotations

import numpy as np

from .cubemap import FACES, face_directions, mip_chain

#: McAllister's discrete exponents (§6.10: "n = 1, 4, 16, 64, 256").
EXPONENTS = (1.0, 4.0, 16.0, 64.0, 256.0)


def exponent_coordinate(n: np.ndarray) -> np.ndarray:
    """t = log₄ n clamped to [0, 4]: the blend coordinate of both representations.

    Linear in log n rather than in n: the maps are spaced geometrically, a
    cosine lobe's width goes as 1/√n so S changes evenly per factor of n,
    and it is what the MIP form does anyway (level = 4 − t).  Exponents
    outside [1, 256] use the end maps (below 1 the lobe is wider than the
    widest map; above 256 the narrowest map blurs the highlight).
    """
    return np.clip(np.log(np.maximum(np.asarray(n, np.float64), 1e-30)) / np.log(4.0), 0.0, len(EXPONENTS) - 1.0)


def discrete_weights(n: np.ndarray) -> np.ndarray:
    """Basis weights ``(R, 5)`` of the discrete maps at exponents ``n (R,)``: hat functions in log₄ n."""
    t = exponent_coordinate(n)
    return np.maximum(0.0, 1.0 - np.abs(t[:, None] - np.arange(len(EXPONENTS))[None, :]))


def prefilter_numpy(source: np.ndarray, exponent: float, size: int, chunk: int = 2048) -> np.ndarray:
    """The brute-force convolution ``(6, size, size, 3)`` of source cube faces ``(6, S, S, 3)`` with (ω̂_p·ω)^n."""
    S = source.shape[1]
    src_dirs, solid = face_directions(S)
    src_dirs = src_dirs.reshape(-1, 3)
    weighted = source.reshape(-1, 3) * solid.reshape(-1, 1)
    out_dirs, _ = face_directions(size)
    out_dirs = out_dirs.reshape(-1, 3)
    out = np.empty((len(out_dirs), 3))
    squarings = int(round(np.log2(exponent))) if exponent >= 1 else -1
    exact = squarings >= 0 and 2.0**squarings == exponent  # 1, 4, …, 256: repeated squaring, much faster than pow
    for s in range(0, len(out_dirs), chunk):
        c = np.maximum(out_dirs[s:s + chunk] @ src_dirs.T, 0.0)
        if exact:
            for _ in range(squarings):
                np.multiply(c, c, out=c)
        else:
            c = np.power(c, exponent)
        out[s:s + chunk] = c @ weighted
    return out.reshape(FACES, size, size, 3)


def mip_sizes(size: int) -> list[int]:
    """Face sizes of the MIP form's prefiltered levels, one per exponent from 256 down to 1."""
    return [max(size >> L, 1) for L in range(len(EXPONENTS))]


def mip_levels(prefiltered: dict[float, np.ndarray]) -> list[np.ndarray]:
    """The MIP form: level L = S(·, 256/4^L) at its size, then box averages of the n = 1 level to 1×1."""
    levels = [prefiltered[e] for e in reversed(EXPONENTS)]
    return levels + mip_chain(levels[-1])[1:]


# -- GL ---------------------------------------------------------------------------------------------------------------

PREFILTER_VS = """#version 330
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 0.0, 1.0); }
"""

PREFILTER_FS = """#version 330
uniform sampler2D u_source;   // source atlas, level 0: 6S x S
uniform int u_source_size;
uniform int u_size;          // output face size
uniform float u_exponent;
out vec4 frag;
vec3 texel_dir(int face, float a, float b) {
    if (face == 0) return vec3(1.0, -b, -a);
    if (face == 1) return vec3(-1.0, -b, a);
    if (face == 2) return vec3(a, 1.0, b);
    if (face == 3) return vec3(a, -1.0, -b);
    if (face == 4) return vec3(a, -b, 1.0);
    return vec3(-a, -b, -1.0);
}
float texel_area(float x, float y) { return atan(x * y, sqrt(x * x + y * y + 1.0)); }
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    int face = px.x / u_size;
    float a = (float(px.x - face * u_size) + 0.5) / float(u_size) * 2.0 - 1.0;
    float b = (float(px.y) + 0.5) / float(u_size) * 2.0 - 1.0;
    vec3 p = normalize(texel_dir(face, a, b));
    vec3 sum = vec3(0.0);
    float S = float(u_source_size);
    for (int f = 0; f < 6; ++f) {
        for (int j = 0; j < u_source_size; ++j) {
            float tb = (float(j) + 0.5) / S * 2.0 - 1.0;
            for (int i = 0; i < u_source_size; ++i) {
                float ta = (float(i) + 0.5) / S * 2.0 - 1.0;
                vec3 d = texel_dir(f, ta, tb);
                float r2 = dot(d, d);
                float c = dot(p, d) * inversesqrt(r2);
                if (c > 0.0) {
                    float x0 = ta - 1.0 / S, x1 = ta + 1.0 / S, y0 = tb - 1.0 / S, y1 = tb + 1.0 / S;
                    float solid = texel_area(x1, y1) - texel_area(x0, y1) - texel_area(x1, y0) + texel_area(x0, y0);
                    sum += exp(u_exponent * log(c)) * solid * texelFetch(u_source, ivec2(f * u_source_size + i, j), 0).rgb;
                }
            }
        }
    }
    frag = vec4(sum, 1.0);
}
"""


def prefilter_gl(ctx, source: np.ndarray, exponents, sizes) -> list[np.ndarray]:
    """The same sums as :func:`prefilter_numpy`, one fragment per output texel, in float32 on the GL device.

    One map per (exponent, size) pair, in order.
    """
    import moderngl

    S = source.shape[1]
    src_img = np.ascontiguousarray(source.transpose(1, 0, 2, 3).reshape(S, FACES * S, 3), np.float32)
    res = []
    try:
        src = ctx.texture((FACES * S, S), 3, src_img.tobytes(), dtype="f4")
        res.append(src)
        src.filter = (moderngl.NEAREST, moderngl.NEAREST)
        prog = ctx.program(vertex_shader=PREFILTER_VS, fragment_shader=PREFILTER_FS)
        res.append(prog)
        quad = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], "f4").tobytes())
        res.append(quad)
        vao = ctx.vertex_array(prog, [(quad, "2f", "in_pos")])
        res.append(vao)
        prog["u_source"].value = 0
        prog["u_source_size"].value = S
        out = []
        for n, size in zip(exponents, sizes):
            tex = ctx.texture((FACES * size, size), 4, dtype="f4")
            fbo = ctx.framebuffer(color_attachments=[tex])
            res += [fbo, tex]
            fbo.use()
            ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            prog["u_size"].value = size
            prog["u_exponent"].value = float(n)
            src.use(0)
            vao.render(moderngl.TRIANGLE_STRIP)
            img = np.frombuffer(fbo.read(components=3, dtype="f4"), np.float32).reshape(size, FACES * size, 3)
            out.append(img.reshape(size, FACES, size, 3).transpose(1, 0, 2, 3).astype(np.float64))
        return out
    finally:
        for r in reversed(res):
            r.release()
