"""BRDF interpolation (seed 000 Ch 5): validity of convex blends, MIP levels three ways, palettes and editing."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from sbrdf_quantizers import edit
from sbrdf_quantizers import interpolate as ip
from sbrdf_quantizers.palette import build_palette, read_palette, resynthesize


def lafortune(registry, lobes=1):
    return registry.create("brdf-model", "lafortune", {"lobes": lobes})


def lobe_maps(V, U, seed=0, lobes=1):
    """Random 1- or 2-lobe Lafortune maps ``name -> (V, U, C)`` within typical ranges."""
    rng = np.random.default_rng(seed)
    p = {"rho_d": rng.uniform(0.02, 0.25, (V, U, 3))}
    for j in range(1, lobes + 1):
        p[f"rho_s_{j}"] = rng.uniform(0.2, 2.0, (V, U, 3))
        p[f"c_xy_{j}"] = rng.uniform(-1.05, -0.9, (V, U, 1)) if j == 1 else rng.uniform(0.8, 1.0, (V, U, 1))
        p[f"c_z_{j}"] = np.ones((V, U, 1))
        p[f"exponent_{j}"] = np.exp(rng.uniform(np.log(3), np.log(200), (V, U, 1)))
    return p


# -- Eq 5.2–5.16 -----------------------------------------------------------------------------------


def two_sampled(registry):
    model = lafortune(registry)
    wi, wo = ip.uniform_pairs(10)
    flat = {k: v.reshape(2, -1) for k, v in lobe_maps(1, 2, seed=4).items()}
    f = ip._eval(model, flat, wi, wo)  # (2, S, 3)
    return f, wi[0], wo[0]


def test_convex_blends_stay_valid(registry):
    f, wi, wo = two_sampled(registry)
    reports = [ip.validity_report(fk, wi, wo) for fk in f]
    assert all(r["non_negative"] and r["reciprocal"] for r in reports)
    for t in np.linspace(0, 1, 11):
        r = ip.validity_report(ip.blend_sampled(f, [1 - t, t]), wi, wo)
        assert r["non_negative"] and r["reciprocal"]
        assert r["energy"] <= max(x["energy"] for x in reports) + 1e-12  # ‖f_ct‖₁ = (1−t)‖f_c0‖₁ + t‖f_c1‖₁
    w = np.random.default_rng(0).dirichlet(np.ones(2), size=20)
    assert all(ip.validity_report(ip.blend_sampled(f, wk), wi, wo)["non_negative"] for wk in w)


def test_extrapolation_goes_negative(registry):
    f, wi, wo = two_sampled(registry)
    r = ip.validity_report(ip.blend_sampled(f, [1001.0, -1000.0]), wi, wo)  # t = −1000
    assert not r["non_negative"] and r["min"] < 0


def test_reciprocity_check_can_fail():
    wi, wo = ip.uniform_pairs(6)
    f = np.repeat((wi[0, :, 2] ** 2)[:, None], 3, axis=1)  # depends on ω_i only: not reciprocal
    assert not ip.validity_report(f, wi[0], wo[0])["reciprocal"]


# -- MIP levels ------------------------------------------------------------------------------------


def test_constant_material_mips_exactly(registry):
    model = lafortune(registry)
    p = {k: np.broadcast_to(v[:1, :1], (4, 4, v.shape[-1])).copy() for k, v in lobe_maps(1, 1).items()}
    ref = ip.brdf_average(model, p)
    assert ip.mip_error(model, ip.mip_lerp(p), ref).max() < 1e-12


def test_refit_beats_parameter_lerp(registry):
    model = lafortune(registry)
    p = lobe_maps(8, 8, seed=2)
    ref = ip.brdf_average(model, p)
    lerp = ip.mip_error(model, ip.mip_lerp(p), ref)
    refit = ip.mip_error(model, ip.mip_refit(model, p), ref)
    assert lerp.shape == refit.shape == (4, 4)
    assert refit.mean() < 0.7 * lerp.mean()
    assert (refit <= lerp * 1.05 + 1e-9).mean() > 0.9  # texel by texel too, almost everywhere


def test_downsampled_samples_ignore_invalid_children():
    f = np.arange(4 * 4 * 2 * 3, dtype=float).reshape(4, 4, 2, 3)
    valid = np.ones((4, 4, 2), bool)
    valid[0, 0, 0] = False
    valid[:2, :2, 1] = False
    fc, vc = ip.downsample_samples(f, valid)
    assert fc.shape == (2, 2, 2, 3) and vc[0, 0, 0] and not vc[0, 0, 1] and vc[1, 1].all()
    np.testing.assert_allclose(fc[0, 0, 0], f[[0, 1, 1], [1, 0, 1], 0].mean(axis=0))


def test_per_level_refit_from_samples(registry):
    from sbrdf_fitters.sample_model import pose_positions

    model = lafortune(registry)
    p = lobe_maps(8, 8, seed=5)
    light, camera = pose_positions("random", 150, 75.0, 600.0, 800.0, 0)
    from sbrdf_core.geometry import tile_directions

    wi, _, wo = tile_directions((8, 8), (100.0, 100.0), (0, 8), (0, 8), light, camera)
    f = model.eval({k: v.reshape(64, -1) for k, v in p.items()}, wi, wo).reshape(8, 8, 150, 3)
    valid = np.broadcast_to(((wi[..., 2] > 0.02) & (wo[..., 2] > 0.02)).reshape(8, 8, 150), f.shape[:3])
    coarse = ip.mip_refit_samples(model, f, valid, (8, 8), (100.0, 100.0), light, camera,
                                  starts_from=ip.mip_lerp(p))
    ref = ip.brdf_average(model, p)
    err = ip.mip_error(model, coarse, ref)
    assert np.isfinite(err).all() and err.mean() < ip.mip_error(model, ip.mip_lerp(p), ref).mean() * 1.5


# -- palette -----------------------------------------------------------------------------------------


def blocky(V=12, U=12, distinct=5, seed=0):
    """A material of ``distinct`` BRDFs in random texels."""
    base = lobe_maps(1, distinct, seed=seed)
    pick = np.random.default_rng(seed + 1).integers(0, distinct, (V, U))
    return {k: v[0][pick] for k, v in base.items()}, pick


def test_palette_with_enough_entries_is_exact(registry):
    model = lafortune(registry)
    p, _ = blocky()
    flat = {k: v.reshape(144, -1) for k, v in p.items()}
    index, palette, _ = build_palette(model, flat, k=5)
    assert len(palette["rho_d"]) == 5
    for k, v in flat.items():
        np.testing.assert_allclose(palette[k][index], v, rtol=1e-6)


def test_more_palette_entries_less_error(registry):
    model = lafortune(registry)
    p = lobe_maps(16, 16, seed=7)
    flat = {k: v.reshape(256, -1) for k, v in p.items()}
    from sbrdf_quantizers.palette import sampled_vectors

    x = sampled_vectors(model, flat)
    errs = []
    for k in (2, 16, 64):
        index, palette, _ = build_palette(model, flat, k=k)
        y = sampled_vectors(model, {n: v[index] for n, v in palette.items()})
        errs.append(np.sqrt(np.mean((x - y) ** 2)))
    assert errs[0] > errs[1] > errs[2]
    with pytest.raises(ValueError, match="k must be in"):
        build_palette(model, flat, k=300)


def test_palette_clusters_what_prepare_computed(registry):
    """Build never computes: ``prepare`` hands the global clustering its inputs as dask work, and ``encode``
    with them gives exactly what ``encode`` computing them itself gives."""
    import dask
    import dask.array as da

    from sbrdf_core.contracts import missing

    model = lafortune(registry)
    params = {k: da.from_array(v, chunks=(4, 4, -1)) for k, v in lobe_maps(8, 8, seed=3).items()}
    quantizer = registry.create("quantizer", "palette", {"k": 4})
    assert missing("quantizer", quantizer) == []
    wanted = quantizer.prepare(params, model)
    assert set(wanted) == {p.name for p in model.parameters} and all(dask.is_dask_collection(v) for v in wanted.values())
    prepared = dict(zip(wanted, dask.compute(*wanted.values())))
    a, b = quantizer.encode(params, model, prepared=prepared), quantizer.encode(params, model)
    for name in a.textures:
        np.testing.assert_array_equal(np.asarray(a.textures[name]), np.asarray(b.textures[name]))


def test_paint_round_trip_replaces_only_changed_texels(tmp_path, registry):
    from sbrdf_core.io import write_png
    from sbrdf_core.runner import run_graph
    from sbrdf_core.store import open_artifact

    text = textwrap.dedent(f"""\
        name: palette
        store: {tmp_path / 's'}
        nodes:
          samples: {{kind: SampleModel, params: {{model: lafortune, texels: [12, 10], poses: 80}}}}
          fit: {{kind: Fit, plugin: lm, in: {{samples: samples}}, params: {{model: lafortune, iterations: 10}}}}
          pal: {{kind: Quantize, plugin: palette, in: {{params: fit}}, params: {{k: 8}}}}
        """)
    run_graph(text, progress=False)
    art = open_artifact(f"{tmp_path / 's'}/pal")
    assert art.attrs["bytes_per_texel"] == 1 and set(art.attrs["files"]) == {"index.png", "palette.json"}
    index, palette = read_palette(art.url)
    assert index.shape == (10, 12) and index.dtype == np.uint8 and index.max() < len(palette["rho_d"])
    fit = open_artifact(f"{tmp_path / 's'}/fit")
    params = {k.split("/", 1)[1]: fit.read(k).astype(np.float64) for k in fit.names() if k.startswith("params/")}
    edited = index.copy()
    edited[2:5, 3:9] = 3  # "paint" a rectangle with entry 3
    write_png(str(tmp_path / "edited.png"), edited)
    from sbrdf_core.io import read_png

    new, changed = resynthesize(params, index, read_png(str(tmp_path / "edited.png")), palette)
    assert (changed == (edited != index)).all() and changed.any()
    for k in params:
        np.testing.assert_array_equal(new[k][~changed], params[k][~changed])  # untouched texels: full precision
        np.testing.assert_allclose(new[k][changed], np.broadcast_to(palette[k][3], new[k][changed].shape))
    bad = index.copy()
    bad[0, 0] = 200
    with pytest.raises(ValueError, match="beyond the palette"):
        resynthesize(params, index, bad, palette)


# -- editing (§4.6) ------------------------------------------------------------------------------------


def test_mask_compositing_selects_layers():
    a, b, c = lobe_maps(6, 6, seed=1), lobe_maps(6, 6, seed=2), lobe_maps(6, 6, seed=3)
    mb = np.zeros((6, 6), bool)
    mb[:, 3:] = True
    mc = np.zeros((6, 6))
    mc[:2] = 1.0
    out = edit.composite([a, b, c], [None, mb, mc])
    for k in a:
        np.testing.assert_array_equal(out[k][4:, :3], a[k][4:, :3])
        np.testing.assert_array_equal(out[k][4:, 3:], b[k][4:, 3:])
        np.testing.assert_array_equal(out[k][:2], c[k][:2])
    with pytest.raises(ValueError, match="mask 1 is"):
        edit.composite([a, b], [None, np.zeros((3, 3), bool)])


def test_diffuse_replacement_keeps_the_mean():
    p = lobe_maps(8, 8, seed=3)
    img = np.random.default_rng(0).uniform(0, 1, (8, 8, 3))
    out = edit.replace_diffuse(p, img)
    np.testing.assert_allclose(out["rho_d"].mean(axis=(0, 1)), p["rho_d"].mean(axis=(0, 1)))
    np.testing.assert_allclose(out["rho_d"] / img, np.broadcast_to(out["rho_d"][0, 0] / img[0, 0], img.shape))
    assert out["exponent_1"] is p["exponent_1"]
    with pytest.raises(ValueError, match="resample it"):
        edit.replace_diffuse(p, img[:4])


def test_cherry_wood_from_a_photo(registry):
    model = lafortune(registry)
    photo = np.random.default_rng(0).integers(0, 256, (32, 32, 3)).astype(np.uint8)
    p = edit.synthesize_from_photo(model, photo, seed=1)
    n = p["exponent_1"][..., 0]
    dark = n == 6.0
    assert 0.05 < dark.mean() < 0.15
    assert abs(n[~dark].mean() - 110) < 0.2 and abs(n[~dark].std() - 1.0) < 0.15
    assert (p["c_xy_1"] == -1.01).all() and (p["c_z_1"] == 0.9).all() and (p["rho_s_1"] == 1).all()
    np.testing.assert_allclose(p["rho_d"], edit.srgb_to_linear(photo) / np.pi)
    # reflectance rises sharply at grazing: the lobe's peak |Cω_i|^110 (notes §9)
    one = {"rho_d": np.zeros((1, 3)), "rho_s_1": np.ones((1, 3)), "c_xy_1": np.array([[-1.01]]),
           "c_z_1": np.array([[0.9]]), "exponent_1": np.array([[110.0]])}
    t = np.radians([0.0, 60.0, 75.0, 89.0])
    wi = np.stack([np.sin(t), 0 * t, np.cos(t)], -1)[None]
    cw = wi * np.array([-1.01, -1.01, 0.9])  # the lobe peaks at ω_r = Cω_i / |Cω_i| (notes §20 item 12)
    peak = model.eval(one, wi, cw / np.linalg.norm(cw, axis=-1, keepdims=True))[0, :, 0]
    np.testing.assert_allclose(peak, [9.3e-6, 0.16, 1.39, 2.98], rtol=0.05)
    with pytest.raises(ValueError, match="1-lobe isotropic"):
        edit.synthesize_from_photo(lafortune(registry, lobes=2), photo)
