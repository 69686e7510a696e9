"""mcallister8: McAllister's 8-bit hardware texture layout (seed 000 §6.5, Fig 6.5), and its shading emulation.

Textures, all 8 bits per channel:

==============  ========  ===========================================================
texture         channels  content
==============  ========  ===========================================================
``rho_d``       RGBA      ρ_d in [0, 1] sr⁻¹ (clamped above: "the uncommon case"), alpha =
                          transparency from the ``alpha`` mask PNG (opaque without one;
                          0 kills the fragment)
``rho_s_<j>``   RGB       lobe j ρ_s after the per-texel rescale, [0, 1]
``lobe_<j>``    RGBA      C_x, C_y, C_z biased by −128 over −1..1 (7 bits) or −2..2
                          (``c_range: 2``, 6 bits, keeps |C| > 1), and n' in alpha
``rho_m``       RGB       mirror term (models with ``mirror: true``)
==============  ========  ===========================================================

**Per-texel rescale.**  A lobe has six degrees of freedom and seven numbers:
(e·ρ_s)·(C')^n = ρ_s·C^n for C' = C·e^(−1/n) (the text's "scaled by ⁿ√e", with
the direction that leaves the BRDF unchanged; notes §11.3, gap 11).  Both of
the text's strategies: ``max`` chooses e so that max(e·ρ_s) = 1 (ρ_s never
clamps); ``balanced`` so that min(e·ρ_s) = min |C'| (e = (c/m)^(n/(n+1)),
precision balanced between the two).  ``none`` keeps the fitted gauge.

**Exponent.**  The text writes "n' = 255 (n/255)² to give more precision for
smaller exponents"; for that purpose the *stored* value must be
n' = 255·√(n/255), so the table column j represents n = 255·(j/255)² (max n
= 255; larger exponents clamp).  That reading (notes §11.3) is the one
implemented and tested.

**Shading emulation** (:func:`hardware_shade`): the GeForce 4 two-pass shader
of §6.7 on these textures: x = C·(ω_i ⊙ ω_r) in float, x' = clamp(x, 0, 1)²
rounded to 8 bits in the p-buffer with n', the dependent read
s = T[x', n'] / 255 in the 256×256 table T[i, j] = (i/255)^((255 (j/255)²)/2)
(:func:`exponent_table`), f = ρ_d + Σ_j ρ_s,j · s_j.  It reproduces the
documented artifacts: no grazing brightening (x > 1 clamped), banding in the
highlight tails (x', n' rounded to 8 bits).  ``decode`` gives the parameters
back for the float (DX9-style ``pow``) path, which has neither.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from sbrdf_core.types import Encoded

from .declarations import MCALLISTER8

RESCALES = ("max", "balanced", "none")


@lru_cache(maxsize=1)
def exponent_table() -> np.ndarray:
    """The 256×256 8-bit lookup table T[i, j] = (i/255)^((255 (j/255)²)/2): row i = x' = x², column j = n'."""
    i = np.arange(256.0)[:, None] / 255.0
    n = 255.0 * (np.arange(256.0)[None, :] / 255.0) ** 2
    with np.errstate(divide="ignore"):
        t = np.power(i, n / 2.0)  # 0^0 = 1: a zero exponent is a constant lobe
    return np.round(255.0 * t).astype(np.uint8)


def encode_exponent(n):
    """n -> n' code: 255·√(n/255), n clamped to [0, 255]."""
    return np.round(255.0 * np.sqrt(np.clip(n, 0.0, 255.0) / 255.0))


def decode_exponent(code):
    """n' code -> n = 255·(n'/255)²."""
    return 255.0 * (np.asarray(code, np.float64) / 255.0) ** 2


def rescale_lobe(rho_s, c, n, strategy: str):
    """Per-texel ``(e·ρ_s, C·e^(−1/n))``: the same lobe, in the gauge ``strategy`` picks.

    ``rho_s`` ``(..., 3)``, ``c`` ``(..., 3)`` (C_x, C_y, C_z), ``n`` ``(..., 1)``.
    """
    rho_s, c, n = (np.asarray(a, np.float64) for a in (rho_s, c, n))
    if strategy == "none":
        return rho_s, c
    if strategy == "max":
        m = rho_s.max(axis=-1, keepdims=True)
        e = np.where(m > 1e-300, 1.0 / np.where(m > 1e-300, m, 1.0), 1.0)  # a subnormal ρ_s is a dead lobe: no rescale
    elif strategy == "balanced":
        m = rho_s.min(axis=-1, keepdims=True)
        cmin = np.abs(c).min(axis=-1, keepdims=True)
        ok = (m > 0) & (cmin > 0) & (n > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            e = np.where(ok, np.exp(n / (n + 1.0) * np.log(np.where(ok, cmin / np.where(m > 0, m, 1.0), 1.0))), 1.0)
    else:
        raise ValueError(f"unknown rescale strategy {strategy!r}; known: {', '.join(RESCALES)}")
    with np.errstate(over="ignore", divide="ignore"):
        k = np.exp(np.clip(-np.log(e) / np.where(n > 0, n, np.inf), -700, 700))
    return rho_s * e, c * k


def _u8(x):
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def _encode_block(packed, model, strategy, c_range, names):
    V, U = packed.shape[:2]
    p = model.unpack(packed.reshape(V * U, -1).astype(np.float64))
    out = [np.concatenate([_u8(255.0 * np.clip(p["rho_d"], 0, 1)), np.full((V * U, 1), 255, np.uint8)], axis=1)]
    for lobe in model.lobe_list(p):
        c = np.concatenate([lobe["c_x"][:, :1], lobe["c_y"][:, :1], lobe["c_z"][:, :1]], axis=1)
        rho_s, c = rescale_lobe(lobe["rho_s"], c, lobe["exponent"][:, :1], strategy)
        out.append(_u8(255.0 * np.clip(rho_s, 0, 1)))
        out.append(np.concatenate([_u8(c * (128.0 / c_range) + 128.0), encode_exponent(lobe["exponent"][:, :1]).astype(np.uint8)],
                                  axis=1))
    if "rho_m" in names:
        out.append(_u8(255.0 * np.clip(p["rho_m"], 0, 1)))
    return np.concatenate(out, axis=1).reshape(V, U, -1)


class McAllister8Quantizer:
    """The hardware layout; ``decode`` is exact given the codes (the only loss is in ``encode``)."""

    params = MCALLISTER8

    def __init__(self, *, rescale: str = "max", c_range: float = 1.0, alpha: str | None = None):
        if rescale not in RESCALES:
            raise ValueError(f"mcallister8: unknown rescale {rescale!r}; known: {', '.join(RESCALES)}")
        if c_range not in (1.0, 2.0):
            raise ValueError(f"mcallister8: c_range must be 1 (−1..1) or 2 (−2..2), not {c_range}")
        self.rescale, self.c_range, self.alpha = rescale, float(c_range), alpha

    #: The hardware's exponent lookup table, for renderers that emulate it (``gf4``) through the registry.
    exponent_table = staticmethod(exponent_table)

    @staticmethod
    def check_params(params) -> list[tuple[str, str]]:
        """The alpha mask is a regular file within the size limit (its pixels are read when the node runs)."""
        alpha = params.get("alpha")
        if alpha is None or "://" in str(alpha):
            return []
        from sbrdf_core.input_files import check_file

        try:
            check_file(alpha)
        except OSError as e:
            return [("alpha", f"cannot read the alpha mask {alpha}: {e.strerror}")]
        return []

    def alpha_codes(self, shape) -> np.ndarray | None:
        """The transparency mask (``alpha``: an 8- or 16-bit PNG of the texel grid; 0 = cut away), as uint8."""
        if self.alpha is None:
            return None
        from sbrdf_core.input_files import check_file
        from sbrdf_core.io.images import read_png

        if "://" not in str(self.alpha):
            check_file(self.alpha)  # a regular file within the size limit: never a FIFO or device read whole
        img = np.asarray(read_png(self.alpha))
        if img.ndim == 3:
            img = img[..., -1] if img.shape[-1] in (2, 4) else img[..., 0]
        if img.shape != tuple(shape):
            raise ValueError(f"mcallister8: alpha mask {self.alpha} is {img.shape[1]}x{img.shape[0]} pixels, "
                             f"the texel grid is {shape[1]}x{shape[0]}")
        scale = 255.0 / (65535.0 if img.dtype == np.uint16 else 255.0)
        return np.clip(np.round(img * scale), 0, 255).astype(np.uint8)

    @staticmethod
    def _check(model):
        if getattr(model, "name", "") != "lafortune" or not hasattr(model, "lobe_list"):
            raise ValueError(f"mcallister8 stores Lafortune lobes; model {model.name!r} has none (use float-exr or fixed16)")
        if model.has_beta:
            raise ValueError("mcallister8: the hardware layout has no β channel; fit with beta: false, or use float-exr")

    def encode(self, params, model) -> Encoded:
        import dask.array as da

        self._check(model)
        names = [p.name for p in model.parameters]
        packed = da.concatenate([da.asarray(params[n]).astype(np.float64) for n in names], axis=-1)
        packed = packed.rechunk(packed.chunks[:2] + (-1,))
        L = model.lobes
        K = 4 + 7 * L + (3 if "rho_m" in names else 0)
        codes = da.map_blocks(_encode_block, packed, model, self.rescale, self.c_range, names, dtype=np.uint8,
                              chunks=packed.chunks[:2] + ((K,),))
        enc = Encoded()
        enc.textures["rho_d"] = codes[..., :4]
        mask = self.alpha_codes(packed.shape[:2])
        if mask is not None:  # ρ_d's alpha is transparency: alpha-kill in the shader
            enc.textures["rho_d"] = da.concatenate(
                [codes[..., :3], da.from_array(mask[..., None], chunks=codes.chunks[:2] + ((1,),))], axis=-1)
        enc.scale["rho_d"], enc.bias["rho_d"] = np.full(4, 1 / 255), np.zeros(4)
        for j in range(1, L + 1):
            k = 4 + 7 * (j - 1)
            enc.textures[f"rho_s_{j}"] = codes[..., k:k + 3]
            enc.scale[f"rho_s_{j}"], enc.bias[f"rho_s_{j}"] = np.full(3, 1 / 255), np.zeros(3)
            enc.textures[f"lobe_{j}"] = codes[..., k + 3:k + 7]
            # C = t·c_range/128 − c_range; the alpha channel decodes to n'/255, squared by decode
            enc.scale[f"lobe_{j}"] = np.array([self.c_range / 128] * 3 + [1 / 255])
            enc.bias[f"lobe_{j}"] = np.array([-self.c_range] * 3 + [0.0])
        if "rho_m" in names:
            enc.textures["rho_m"] = codes[..., K - 3:]
            enc.scale["rho_m"], enc.bias["rho_m"] = np.full(3, 1 / 255), np.zeros(3)
        return enc

    def decode(self, textures, scale, bias, model):
        self._check(model)
        val = {k: t.astype(np.float64) * scale[k] + bias[k] for k, t in textures.items()}
        out = {"rho_d": val["rho_d"][..., :3]}
        for j in range(1, model.lobes + 1):
            lobe = val[f"lobe_{j}"]
            out[f"rho_s_{j}"] = val[f"rho_s_{j}"]
            if model.anisotropic:
                out[f"c_x_{j}"], out[f"c_y_{j}"] = lobe[..., 0:1], lobe[..., 1:2]
            else:
                out[f"c_xy_{j}"] = lobe[..., 0:1]
            out[f"c_z_{j}"] = lobe[..., 2:3]
            out[f"exponent_{j}"] = 255.0 * lobe[..., 3:4] ** 2
        if "rho_m" in val:
            out["rho_m"] = val["rho_m"]
        if val["rho_d"].shape[-1] == 4:  # transparency for renderers' alpha-kill (not a model parameter)
            out["alpha"] = val["rho_d"][..., 3:4]
        return out

    def bytes_per_texel(self, textures):
        return int(sum(t.shape[-1] for t in textures.values()))


def hardware_shade(textures, scale, bias, wi, wo, clamp_x: bool = True, lut: bool = True) -> np.ndarray:
    """f_r as the GeForce 4 shader computes it from the 8-bit textures, ``(T, S, 3)`` sr⁻¹.

    ``textures`` hold ``(T, K)`` (or ``(V, U, K)``, flattened) uint8 codes; ``wi``, ``wo`` are
    ``(T, S, 3)``.  ``clamp_x=False`` and ``lut=False`` switch off the two documented
    artifacts one at a time (``False, False`` is the float ``pow`` path on 8-bit parameters).
    The alpha channel of ``rho_d`` kills a texel (f = 0) where it is 0.
    """
    flat = {k: np.asarray(t).reshape(-1, np.asarray(t).shape[-1]) for k, t in textures.items()}
    val = {k: flat[k].astype(np.float64) * scale[k] + bias[k] for k in flat}
    f = np.broadcast_to(val["rho_d"][:, None, :3], wi.shape[:2] + (3,)).copy()
    table = exponent_table()
    up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    j = 1
    while f"lobe_{j}" in flat:
        c = val[f"lobe_{j}"][:, None, :3]
        x = np.einsum("tsk,tsk->ts", c * wi, wo)
        n_code = flat[f"lobe_{j}"][:, 3].astype(np.int64)
        if lut:
            xp = np.clip(x, 0.0, 1.0) ** 2 if clamp_x else np.maximum(x, 0.0) ** 2
            i = np.clip(np.round(255.0 * xp), 0, 255).astype(np.int64)  # the p-buffer is 8 bits
            s = table[i, n_code[:, None]] / 255.0
        else:
            n = decode_exponent(n_code)[:, None]
            xc = np.clip(x, 0.0, 1.0) if clamp_x else np.maximum(x, 0.0)
            with np.errstate(divide="ignore"):
                s = np.where(xc > 0, np.exp(np.clip(n * np.log(np.where(xc > 0, xc, 1.0)), -745, 60)), 0.0)
        f += val[f"rho_s_{j}"][:, None, :] * s[..., None]
        j += 1
    alive = (flat["rho_d"][:, 3] > 0)[:, None]
    return np.where((up & alive)[..., None], f, 0.0)
