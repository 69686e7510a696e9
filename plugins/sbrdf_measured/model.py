"""merl: a tabulated isotropic BRDF read from a MERL binary file, rendered on ``cpu`` and ``gl``.

    f_r(ω_i, ω_o) = scale · table(θh, θd, φd)      per RGB channel

The table is material-global (one file); the only per-texel parameter is an
RGB ``scale`` (1 = the measured material), so parameter maps, quantizers,
``Fit`` (the scale is linear: a least-squares solve) and the model contract
checks apply.  Lookup (:mod:`.merl`): ``trilinear`` (default) or ``nearest``
(exactly ``BRDFRead.cpp``'s).  ``path: null`` is a placeholder without a file,
f_r = scale/π, so the model can be listed and checked with its defaults.

GL: :meth:`gl_textures` gives the table as one RGBA float32 2D atlas
``merl_table`` (the gl renderer uploads 2D textures): θh slice i is the tile
at column ``i % cols``, row ``i // cols``, each tile ``n_φd`` texels wide and
``n_θd`` high; alpha is 1 where measured.  :meth:`glsl` fetches the eight
corners with ``texelFetch`` and blends them as :meth:`eval` does, so both
agree to float32 round-off whatever sampler state is bound (ES 3.00 too).

Relative paths in ``path`` resolve from the graph file where the model is a
node's ``model_params``; a scene file's ``model_params`` are not resolved by
the scene loader, so give scenes an absolute path (or one relative to the cwd).

YAML::

    materials: {m: {model: merl, model_params: {path: /data/merl/gold-metallic-paint.binary}, params: {scale: 1}}}
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.brdf import BRDFModel, ModelParameter

from .declarations import MERL
from .merl import MerlTable, load_cached

INV_PI = 1.0 / np.pi


class MerlModel(BRDFModel):
    name = "merl"
    anisotropic = False
    suggested_starts = 1
    parameters = (
        ModelParameter("scale", 3, (0.0, 100.0), (0.5, 1.5), 1.0, unit="1", magnitude=True,
                       doc="RGB multiplier of the measured table (1 = the material as measured)"),
    )

    params = MERL

    def __init__(self, *, path: str | None = None, interpolation: str = "trilinear"):
        self.path, self.interpolation = path, interpolation
        self._table: MerlTable | None = None

    def __getstate__(self):  # dask pickles models into tasks: the table is re-read (cached) where it is used
        state = dict(self.__dict__)
        state["_table"] = None
        return state

    @property
    def table(self) -> MerlTable | None:
        if self._table is None and self.path is not None:
            self._table = load_cached(self.path)
        return self._table

    def set_table(self, table: MerlTable) -> None:
        """Use an in-memory table (tests, a node that just read one)."""
        self._table = table

    # -- BRDFModel ---------------------------------------------------------------------------------------------

    def basis(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """The table at ``(T, S)`` pairs, ``(T, S, 3)``; 0 below the horizon and where nothing was measured."""
        table = self.table
        if table is None:
            up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
            return np.where(up[..., None], INV_PI, 0.0) * np.ones(wi.shape[:-1] + (3,))
        f, _ = table.lookup(wi, wo, self.interpolation)
        return f

    def eval(self, params, wi, wo):
        return np.asarray(params["scale"], np.float64)[:, None, :] * self.basis(wi, wo)

    def jacobian(self, params, wi, wo):
        return self.basis(wi, wo)[..., :, None] * np.eye(3)

    def initial_guess(self, f_r, valid, wi, wo):
        """Least-squares RGB scale of the table to each texel's samples."""
        b = self.basis(wi, wo)
        v = np.asarray(valid, bool)[..., None]
        num = np.where(v, np.nan_to_num(f_r) * b, 0.0).sum(axis=1)
        den = np.where(v, b * b, 0.0).sum(axis=1)
        return {"scale": np.clip(np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0), 0.0, 100.0)}

    def gl_textures(self) -> dict[str, np.ndarray]:
        """``merl_table`` -> the RGBA float32 atlas :meth:`glsl` reads (nothing without a table)."""
        table = self.table
        if table is None:
            return {}
        return {"merl_table": atlas(table)}

    def glsl(self) -> str:
        """``vec3 brdf_merl(vec3 wi, vec3 wo, vec3 scale)`` with its sampler and lookup code."""
        table = self.table
        if table is None:
            return ("vec3 brdf_merl(vec3 wi, vec3 wo, vec3 scale) {\n"
                    "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
                    f"    return scale * {INV_PI:.10f};\n}}\n")
        n_th, n_td, n_pd = table.dims
        return GLSL.format(n_th=n_th, n_td=n_td, n_pd=n_pd, cols=atlas_columns(table.dims),
                           nearest="true" if self.interpolation == "nearest" else "false")


def atlas_columns(dims) -> int:
    n_th, _, n_pd = dims
    return int(max(1, min(n_th, 4096 // n_pd)))


def atlas(table: MerlTable) -> np.ndarray:
    """The table as a 2D RGBA float32 image ``(rows · n_θd, cols · n_φd, 4)``, alpha = measured."""
    n_th, n_td, n_pd = table.dims
    cols = atlas_columns(table.dims)
    rows = -(-n_th // cols)
    out = np.zeros((rows * n_td, cols * n_pd, 4), np.float32)
    rgba = np.concatenate([table.f_r, table.measured[..., None].astype(np.float64)], axis=-1).astype(np.float32)
    for i in range(n_th):
        r, c = divmod(i, cols)
        out[r * n_td:(r + 1) * n_td, c * n_pd:(c + 1) * n_pd] = rgba[i]
    return out


GLSL = """uniform sampler2D merl_table;
const int MERL_NTH = {n_th};
const int MERL_NTD = {n_td};
const int MERL_NPD = {n_pd};
const int MERL_COLS = {cols};
const bool MERL_NEAREST = {nearest};
vec4 merl_texel(int i, int j, int k) {{
    return texelFetch(merl_table, ivec2((i % MERL_COLS) * MERL_NPD + k, (i / MERL_COLS) * MERL_NTD + j), 0);
}}
vec3 merl_lookup(vec3 wi, vec3 wo) {{
    const float PI_ = 3.14159265358979;
    vec3 s = wi + wo;
    float ls = length(s);
    vec3 h = s / ls;
    float r = length(h.xy);
    float th = atan(r, h.z);
    vec2 cs = r > 0.0 ? h.xy / r : vec2(1.0, 0.0);
    vec3 d = wi - wo;
    float td = atan(length(d), ls);
    float x = d.x * h.z * cs.x + d.y * h.z * cs.y - d.z * r;
    float y = -d.x * cs.y + d.y * cs.x;
    if (y < 0.0 || (y == 0.0 && x < 0.0)) {{ x = -x; y = -y; }}
    float pd = (x == 0.0 && y == 0.0) ? 0.0 : atan(y, x);
    if (pd >= PI_) pd = 0.0;
    float u = sqrt(th / (0.5 * PI_)) * float(MERL_NTH);
    float v = td / (0.5 * PI_) * float(MERL_NTD);
    float w = pd / PI_ * float(MERL_NPD);
    if (MERL_NEAREST) {{
        vec4 c = merl_texel(clamp(int(floor(u)), 0, MERL_NTH - 1), clamp(int(floor(v)), 0, MERL_NTD - 1),
                            clamp(int(floor(w)), 0, MERL_NPD - 1));
        return c.a > 0.5 ? c.rgb : vec3(0.0);
    }}
    u = clamp(u, 0.0, float(MERL_NTH - 1));
    v = clamp(v, 0.0, float(MERL_NTD - 1));
    int i0 = min(int(floor(u)), MERL_NTH - 1);
    int j0 = min(int(floor(v)), MERL_NTD - 1);
    int k0 = int(floor(w));
    float fu = u - float(i0), fv = v - float(j0), fw = w - float(k0);
    int i1 = min(i0 + 1, MERL_NTH - 1), j1 = min(j0 + 1, MERL_NTD - 1);
    k0 = ((k0 % MERL_NPD) + MERL_NPD) % MERL_NPD;
    int k1 = (k0 + 1) % MERL_NPD;
    vec3 acc = vec3(0.0);
    float wsum = 0.0;
    for (int a = 0; a < 2; ++a) {{
        int ii = a == 0 ? i0 : i1;
        float wu = a == 0 ? 1.0 - fu : fu;
        for (int b = 0; b < 2; ++b) {{
            int jj = b == 0 ? j0 : j1;
            float wv = b == 0 ? 1.0 - fv : fv;
            for (int c = 0; c < 2; ++c) {{
                int kk = c == 0 ? k0 : k1;
                float ww = c == 0 ? 1.0 - fw : fw;
                vec4 t = merl_texel(ii, jj, kk);
                float wt = wu * wv * ww * t.a;
                acc += wt * t.rgb;
                wsum += wt;
            }}
        }}
    }}
    return wsum > 0.0 ? acc / wsum : vec3(0.0);
}}
vec3 brdf_merl(vec3 wi, vec3 wo, vec3 scale) {{
    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);
    return scale * merl_lookup(wi, wo);
}}
"""
