"""McAllister's 8-bit layout: exponent table and remap, ρ_s/C rescale, and the documented artifacts (seed 000 §6.5, §6.8)."""

from __future__ import annotations

import dask.array as da
import numpy as np
import pytest

from sbrdf_quantizers.float_exr import FloatEXRQuantizer
from sbrdf_quantizers.mcallister8 import (
    McAllister8Quantizer,
    decode_exponent,
    encode_exponent,
    exponent_table,
    hardware_shade,
    rescale_lobe,
)


def lafortune(registry, **cfg):
    return registry.create("brdf-model", "lafortune", {"lobes": 1, **cfg})


def maps(params: dict) -> dict:
    """``(T, C)`` NumPy -> ``(1, T, C)`` dask maps, the shape the Quantize node hands a layout."""
    return {k: da.from_array(np.asarray(v, np.float64)[None]) for k, v in params.items()}


def encode_decode(q, model, params):
    enc = q.encode(maps(params), model)
    tex = {k: np.asarray(t.compute() if hasattr(t, "compute") else t)[0] for k, t in enc.textures.items()}
    scale = {k: np.asarray(s) for k, s in enc.scale.items()}
    bias = {k: np.asarray(b) for k, b in enc.bias.items()}
    dec = q.decode(tex, scale, bias, model)
    return tex, scale, bias, dec


def test_exponent_table_is_the_documented_formula():
    T = exponent_table()
    assert T.shape == (256, 256) and T.dtype == np.uint8
    i, j = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")
    exact = 255 * (i / 255.0) ** ((255 * (j / 255.0) ** 2) / 2)
    assert np.abs(T - exact).max() <= 0.5 + 1e-9  # each entry is the formula rounded to 8 bits
    assert (T[255] == 255).all() and (T[:, 0] == 255).all() and (T[0, 1:] == 0).all()
    assert (np.diff(T.astype(int), axis=0) >= 0).all() and (np.diff(T.astype(int), axis=1) <= 0).all()
    # lookup(x², n') ≈ x^n to within the 8-bit errors: the table entry's rounding plus what rounding x' to
    # 8 bits in the p-buffer can move x'^(n/2) by
    x = np.linspace(0, 1, 1001)
    h = 0.5 / 255
    for n in (1.0, 4.0, 16.0, 64.0, 200.0):
        code = encode_exponent(n).astype(int)
        m = decode_exponent(code)
        got = T[np.round(255 * x ** 2).astype(int), code] / 255.0
        bound = np.minimum(x ** 2 + h, 1) ** (m / 2) - np.maximum(x ** 2 - h, 0) ** (m / 2) + h
        assert (np.abs(got - x ** m) <= bound + 1e-12).all()
    # and the x' = x² row remap is what makes sharp lobes usable: indexing rows by x directly is worse near x = 1
    x = np.linspace(0.9, 1.0, 501)
    code = encode_exponent(200.0).astype(int)
    m = decode_exponent(code)
    remapped = np.abs(T[np.round(255 * x ** 2).astype(int), code] / 255.0 - x ** m).max()
    direct = np.abs(np.round(255 * (np.round(255 * x) / 255) ** m) / 255 - x ** m).max()
    assert remapped < direct


def test_exponent_remap_gives_small_exponents_more_codes():
    assert encode_exponent(255.0) == 255 and encode_exponent(0.0) == 0 and encode_exponent(1e4) == 255
    n = np.array([1.0, 2.0, 4.0, 8.0])
    err = np.abs(decode_exponent(encode_exponent(n)) - n)
    assert (err < 0.1).all()  # a linear 8-bit map over 0..255 has steps of 1
    # the step between codes grows with n: (2j + 1)/255
    steps = np.diff(decode_exponent(np.arange(256)))
    assert steps[0] < 0.01 and steps[-1] > 1.9 and (np.diff(steps) > 0).all()


@pytest.mark.parametrize("strategy", ["max", "balanced"])
def test_rescale_leaves_the_brdf_unchanged(registry, strategy):
    model = lafortune(registry)
    rng = np.random.default_rng(1)
    T = 200
    params = {"rho_d": rng.uniform(0, 0.2, (T, 3)), "rho_s_1": rng.uniform(0.05, 5.0, (T, 3)),
              "c_xy_1": rng.uniform(-1.1, -0.3, (T, 1)), "c_z_1": rng.uniform(0.3, 1.1, (T, 1)),
              "exponent_1": rng.uniform(1, 250, (T, 1))}
    c = np.concatenate([params["c_xy_1"], params["c_xy_1"], params["c_z_1"]], axis=1)
    rho_s, c2 = rescale_lobe(params["rho_s_1"], c, params["exponent_1"], strategy)
    moved = {**params, "rho_s_1": rho_s, "c_xy_1": c2[:, :1], "c_z_1": c2[:, 2:3]}
    d = np.random.default_rng(2).normal(size=(T, 64, 2, 3))
    d[..., 2] = np.abs(d[..., 2])
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    a, b = model.eval(params, d[:, :, 0], d[:, :, 1]), model.eval(moved, d[:, :, 0], d[:, :, 1])
    np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12)
    if strategy == "max":
        np.testing.assert_allclose(rho_s.max(axis=1), 1.0)
    else:
        np.testing.assert_allclose(rho_s.min(axis=1), np.abs(c2).min(axis=1), rtol=1e-9)
    assert not np.allclose(rho_s, params["rho_s_1"])  # it did move the gauge


def test_hardware_decode_is_exact_on_representable_values(registry):
    model = lafortune(registry)
    # values on the 8-bit grids: ρ = k/255, C = (t − 128)/128, n = 255 (j/255)²
    params = {"rho_d": np.array([[10, 20, 30]]) / 255.0, "rho_s_1": np.array([[255, 128, 64]]) / 255.0,
              "c_xy_1": np.array([[-100 / 128]]), "c_z_1": np.array([[90 / 128]]),
              "exponent_1": np.array([[255 * (100 / 255) ** 2]])}
    _, _, _, dec = encode_decode(McAllister8Quantizer(rescale="none"), model, params)
    for k, v in params.items():
        np.testing.assert_allclose(dec[k], v, rtol=0, atol=1e-12, err_msg=k)


def mirror_pairs(theta_deg):
    t = np.radians(np.asarray(theta_deg, float))
    wi = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=-1)
    wo = wi * np.array([-1, -1, 1])
    return wi[None], wo[None]


CHERRY = {"rho_d": np.array([[0.05, 0.04, 0.03]]), "rho_s_1": np.array([[1.0, 1.0, 1.0]]),
          "c_xy_1": np.array([[-1.01]]), "c_z_1": np.array([[0.9]]), "exponent_1": np.array([[110.0]])}


def test_no_grazing_brightening_when_x_is_clamped(registry):
    """C = (−1.01, −1.01, 0.9), n = 110: the float path rises to ≈ 3 at 89°, the 8-bit shader stays ≤ ρ_d + ρ_s."""
    model = lafortune(registry)
    theta = np.array([0.0, 60.0, 75.0, 85.0, 89.0])
    wi, wo = mirror_pairs(theta)
    tex32, s32, b32, dec32 = encode_decode(FloatEXRQuantizer(dtype="float32"), model, CHERRY)
    f_float = model.eval(dec32, wi, wo)[0, :, 0] - CHERRY["rho_d"][0, 0]
    assert f_float[0] < 1e-4 and f_float[-1] > 2.5 and (np.diff(f_float) > 0).all()
    tex, scale, bias, dec = encode_decode(McAllister8Quantizer(rescale="none", c_range=2.0), model, CHERRY)
    rho_d8 = dec["rho_d"][0, 0]
    f_hw = hardware_shade(tex, scale, bias, wi, wo)[0, :, 0] - rho_d8
    assert f_hw.max() <= 1.0 + 1e-12 and f_hw[-1] < 0.5 * f_float[-1]
    # the clamp, not the 8-bit parameters, removes it: float pow on the same codes brightens again
    f_unclamped = hardware_shade(tex, scale, bias, wi, wo, clamp_x=False, lut=False)[0, :, 0] - rho_d8
    assert f_unclamped[-1] > 2.0
    # with the −1..1 mapping C_x = −1.01 itself clamps to −1
    _, _, _, dec1 = encode_decode(McAllister8Quantizer(rescale="none", c_range=1.0), model, CHERRY)
    assert abs(dec1["c_xy_1"][0, 0]) <= 1.0


def tail_sweep(n_points=400):
    """ω_i at 30°, ω_r swept away from the mirror direction through a lobe's tail."""
    t = np.radians(30.0)
    wi = np.broadcast_to(np.array([np.sin(t), 0, np.cos(t)]), (n_points, 3))
    a = np.radians(np.linspace(0.0, 25.0, n_points)) + t
    wo = np.stack([-np.sin(a), np.zeros_like(a), np.cos(a)], axis=-1)
    return wi[None], wo[None]


def test_highlight_tails_band_in_8_bit_and_not_in_float(registry):
    model = lafortune(registry)
    params = {"rho_d": np.zeros((1, 3)), "rho_s_1": np.ones((1, 3)), "c_xy_1": np.array([[-1.0]]),
              "c_z_1": np.array([[1.0]]), "exponent_1": np.array([[64.0]])}
    wi, wo = tail_sweep()
    _, _, _, dec32 = encode_decode(FloatEXRQuantizer(dtype="float32"), model, params)
    f = model.eval(dec32, wi, wo)[0, :, 0]
    tail = f > 1e-3
    assert (np.diff(f[tail]) < 0).all()  # float: strictly decreasing, every sample its own value
    tex, scale, bias, _ = encode_decode(McAllister8Quantizer(rescale="none"), model, params)
    h = hardware_shade(tex, scale, bias, wi, wo)[0, :, 0]
    ht = h[tail]
    assert len(np.unique(ht)) < 0.25 * tail.sum()  # plateaus: neighbours hit the same table entry
    runs = np.diff(np.flatnonzero(np.diff(ht) != 0))
    assert runs.max() >= 5
    assert np.abs(np.diff(ht)).max() > 3 * np.abs(np.diff(f[tail])).max()  # and jumps between them


def test_alpha_mask_is_stored_and_kills_texels(registry, tmp_path):
    """ρ_d's alpha is transparency (§6.5): read from a mask PNG, alpha 0 gives f_r = 0 in the hardware shader."""
    from sbrdf_core.io.images import write_png

    model = lafortune(registry)
    params = {k: np.repeat(v, 4, axis=0) for k, v in CHERRY.items()}
    mask = np.array([[255, 0, 255, 128]], np.uint8)
    write_png(str(tmp_path / "alpha.png"), mask)
    tex, scale, bias, dec = encode_decode(McAllister8Quantizer(alpha=str(tmp_path / "alpha.png")), model, params)
    np.testing.assert_array_equal(tex["rho_d"][:, 3], mask[0])
    assert set(dec) == set(params) | {"alpha"}  # alpha rides along for renderers' alpha-kill; not a BRDF parameter
    np.testing.assert_array_equal(dec["alpha"][..., 0] > 0.5, mask[0] >= 128)
    wi, wo = mirror_pairs([30.0] * 4)
    wi, wo = np.repeat(wi, 4, axis=0), np.repeat(wo, 4, axis=0)
    f = hardware_shade({k: t for k, t in tex.items()}, scale, bias, wi, wo)
    assert (f[1] == 0).all() and (f[0] > 0).all()
    with pytest.raises(ValueError, match="alpha mask .* 4x1 pixels, the texel grid is 5x1"):
        McAllister8Quantizer(alpha=str(tmp_path / "alpha.png")).alpha_codes((1, 5))
