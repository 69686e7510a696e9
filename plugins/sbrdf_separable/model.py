"""separable: a BRDF as a sum of products of 2D factor textures (Kautz & McCool 1999, seed 001).

    f_r(ω_i, ω_o) = scale · Σ_k g_k(x(ω_i, ω_o)) h_k(y(ω_i, ω_o))      per RGB channel

x, y come from a ``parameterization`` plugin (gram-schmidt, rusinkiewicz,
standard, elevation-azimuth); g_k, h_k are K × K RGB textures looked up
bilinearly (:func:`.factors.bilinear`, GL_LINEAR with clamp-to-edge, repeat
on periodic axes).  The factors are material-global and live in a
``SeparableFactors`` store written by the ``svd`` / ``nd`` fitters; the only
per-texel parameter is an RGB ``scale`` (1 = the decomposed material).

Configuration: ``factors`` (the store's path; ``null`` gives one constant
term, f_r = scale/π, a placeholder with no textures) and ``terms`` (use the
first N terms only).  The approximation is exactly reciprocal only for the
``standard`` parameterization with symmetric factors; measure with
``sbrdf_core.brdf_checks.reciprocity_error``.

GL: :meth:`gl_textures` gives the factor textures as ``(K, K, 3)`` float32
arrays named ``sep_g<k>``, ``sep_h<k>``; :meth:`glsl` declares them as
``uniform sampler2D`` and defines ``vec3 brdf_separable(vec3 wi, vec3 wo,
vec3 scale)`` in the surface frame, filtering by hand with ``texelFetch`` so
the result matches :meth:`eval` whatever sampler state is bound.

YAML::

    fit: {kind: Fit, plugin: nd, in: {samples: material},
          params: {parameterization: gram-schmidt, size: 64, factors: runs/ward-nd.zarr}}
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.brdf import BRDFModel, ModelParameter, above_horizon
from sbrdf_core.contracts import Parameterization

from .declarations import SEPARABLE
from .factors import Factors, bilinear, load

INV_PI = 1.0 / np.pi


class SeparableModel(BRDFModel):
    name = "separable"
    parameters = (
        ModelParameter("scale", 3, (0.0, 100.0), (0.5, 1.5), 1.0, unit="1",
                       doc="RGB multiplier of the material-global factor product"),
    )

    params = SEPARABLE

    def __init__(self, *, factors: str | None = None, terms: int | None = None):
        self.factors_url, self.terms = factors, terms
        self._factors: Factors | None = None
        self._param: Parameterization | None = None  # the factors' parameterization, set with them
        #: Renderers need the tangent frame: every parameterization but a constant one (no factors) refers to t.
        self.anisotropic = factors is not None

    # -- factors ------------------------------------------------------------------------------------

    @property
    def factors(self) -> Factors | None:
        """The factor textures, read from the store on first use (a Fit node builds the model before they exist)."""
        if self._factors is None and self.factors_url is not None:
            self.set_factors(load(self.factors_url))
        return self._factors

    def set_factors(self, factors: Factors) -> None:
        from .decompose import parameterization

        self._factors = factors.truncated(self.terms) if self.terms else factors
        self._param = parameterization(factors.parameterization, factors.parameterization_config)
        self.anisotropic = True

    def basis(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """Σ_k g_k h_k at ``(T, S)`` pairs, ``(T, S, 3)``; 0 below the horizon."""
        up = above_horizon(wi, wo)
        fac = self.factors
        if fac is None:
            return np.where(up[..., None], INV_PI, 0.0) * np.ones(wi.shape[:-1] + (3,))
        assert self._param is not None, "set_factors() sets the parameterization with the factors"
        shape = wi.shape[:-1]
        safe_i = np.where(up[..., None], wi, (0.0, 0.0, 1.0)).reshape(-1, 3)
        safe_o = np.where(up[..., None], wo, (0.0, 0.0, 1.0)).reshape(-1, 3)
        x, y = self._param.coords(safe_i, safe_o)
        wx, wy = self._param.wrap
        f = np.einsum("ksc,ksc->sc", bilinear(fac.g, x, wx), bilinear(fac.h, y, wy))
        return np.where(up[..., None], f.reshape(shape + (3,)), 0.0)

    # -- BRDFModel ------------------------------------------------------------------------------------

    def eval(self, params, wi, wo):
        return np.asarray(params["scale"], float)[:, None, :] * self.basis(wi, wo)

    def jacobian(self, params, wi, wo):
        b = self.basis(wi, wo)
        return b[..., :, None] * np.eye(3)

    def initial_guess(self, f_r, valid, wi, wo):
        """Least-squares RGB scale of the factor product to each texel's samples."""
        b = self.basis(wi, wo)
        v = np.asarray(valid, bool)[..., None]
        num = np.where(v, f_r * b, 0.0).sum(axis=1)
        den = np.where(v, b * b, 0.0).sum(axis=1)
        return {"scale": np.clip(np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0), 0.0, 100.0)}

    def gl_textures(self) -> dict[str, np.ndarray]:
        """``sep_g<k>``, ``sep_h<k>`` -> ``(K, K, 3)`` float32 (row = v), the samplers :meth:`glsl` reads."""
        fac = self.factors
        if fac is None:
            return {}
        out = {}
        for k in range(fac.terms):
            out[f"sep_g{k}"] = np.ascontiguousarray(fac.g[k], np.float32)
            out[f"sep_h{k}"] = np.ascontiguousarray(fac.h[k], np.float32)
        return out

    def glsl(self) -> str:
        """``vec3 brdf_separable(vec3 wi, vec3 wo, vec3 scale)`` plus its samplers and coordinate code."""
        fac = self.factors
        if fac is None:
            return ("vec3 brdf_separable(vec3 wi, vec3 wo, vec3 scale) {\n"
                    "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
                    f"    return scale * {INV_PI:.10f};\n}}\n")
        assert self._param is not None, "set_factors() sets the parameterization with the factors"
        (wxu, wxv), (wyu, wyv) = self._param.wrap
        b = lambda v: "true" if v else "false"  # noqa: E731
        decl = "".join(f"uniform sampler2D sep_g{k};\nuniform sampler2D sep_h{k};\n" for k in range(fac.terms))
        terms = "".join(
            f"    f += sep_fetch(sep_g{k}, x, bvec2({b(wxu)}, {b(wxv)})) * sep_fetch(sep_h{k}, y, bvec2({b(wyu)}, {b(wyv)}));\n"
            for k in range(fac.terms))
        return (
            decl + self._param.glsl() + FETCH +
            "vec3 brdf_separable(vec3 wi, vec3 wo, vec3 scale) {\n"
            "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
            "    vec2 x, y;\n"
            "    sep_coords(wi, wo, x, y);\n"
            "    vec3 f = vec3(0.0);\n" + terms +
            "    return scale * f;\n"
            "}\n")


#: GL_LINEAR by hand: texel centres at (i + 0.5)/K, clamp-to-edge or repeat per axis.
FETCH = """vec3 sep_fetch(sampler2D t, vec2 uv, bvec2 wrap) {
    ivec2 size = textureSize(t, 0);
    vec2 s = uv * vec2(size) - 0.5;
    vec2 f0 = floor(s);
    vec2 fr = s - f0;
    ivec2 i0 = ivec2(f0);
    ivec2 i1 = i0 + 1;
    for (int a = 0; a < 2; ++a) {
        if (wrap[a]) {  // GLSL leaves % of negative operands undefined: floor division instead
            i0[a] -= size[a] * int(floor(float(i0[a]) / float(size[a])));
            i1[a] -= size[a] * int(floor(float(i1[a]) / float(size[a])));
        }
        else { i0[a] = clamp(i0[a], 0, size[a] - 1); i1[a] = clamp(i1[a], 0, size[a] - 1); }
    }
    vec3 top = mix(texelFetch(t, ivec2(i0.x, i0.y), 0).rgb, texelFetch(t, ivec2(i1.x, i0.y), 0).rgb, fr.x);
    vec3 bottom = mix(texelFetch(t, ivec2(i0.x, i1.y), 0).rgb, texelFetch(t, ivec2(i1.x, i1.y), 0).rgb, fr.x);
    return mix(top, bottom, fr.y);
}
"""
