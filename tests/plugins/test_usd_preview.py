"""sbrdf_lib.usd_preview: UsdPreviewSurface's BRDF as Storm shades it, and the conversion that fits it."""

from __future__ import annotations

import numpy as np
import pytest

from sbrdf_core.registry import Registry
from sbrdf_lib import convert as cv
from sbrdf_lib.usd_preview import PreviewSurface, ior_of, to_preview_surface


@pytest.fixture(scope="module")
def reg():
    return Registry()


@pytest.fixture(scope="module")
def ggx(reg):
    return cv.ggx_model(reg)


def storm(inputs: dict, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Storm's ``evaluateLight`` (previewSurface.glslfx, specular workflow) for one texel, sample by sample.

    ``inputs`` are USD's own: diffuseColor, specularColor, roughness, clearcoat, clearcoatRoughness, ior.
    """
    eps = 1e-3

    def spec(f0, f90, rough, fresnel, nl, ne, nh):
        a2 = max(rough, 1e-3) ** 4
        D = (a2 + eps) / (np.pi * (nh * nh * (a2 - 1.0) + 1.0) ** 2)
        k = max(rough, 1e-3) ** 2 * 0.5
        G = ne / (ne * (1 - k) + k) * nl / (nl * (1 - k) + k)
        return (f0 + (f90 - f0) * fresnel) * G * D / (4.0 * nl * ne + eps)

    out = np.zeros((len(wi), 3))
    R = ((1.0 - inputs["ior"]) / (1.0 + inputs["ior"])) ** 2
    for s, (l, e) in enumerate(zip(wi, wo)):
        if l[2] <= 0 or e[2] <= 0:
            continue
        h = (l + e) / np.linalg.norm(l + e)
        nl, ne, nh, eh = l[2], e[2], h[2], float(e @ h)
        fresnel = max(0.0, 1.0 - eh) ** 5
        F0 = np.asarray(inputs["specularColor"], float)
        d = np.asarray(inputs["diffuseColor"], float) / np.pi * (1.0 - (F0 + (1.0 - F0) * fresnel))
        s1 = spec(F0, 1.0, inputs["roughness"], fresnel, nl, ne, nh)
        s2 = inputs["clearcoat"] * spec(R, 1.0, inputs["clearcoatRoughness"], fresnel, nl, ne, nh)
        out[s] = d + s1 + s2
    return out


def random_params(T: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return {"diffuse_color": rng.uniform(0, 1, (T, 3)), "specular_color": rng.uniform(0, 1, (T, 3)),
            "roughness": rng.uniform(0.1, 1, (T, 1)), "clearcoat": rng.uniform(0, 1, (T, 1)),
            "clearcoat_f0": rng.uniform(0, 0.8, (T, 1)), "clearcoat_roughness": rng.uniform(0.1, 1, (T, 1))}


def test01_create_parameters_in_usds_ranges():
    m = PreviewSurface()
    assert [p.name for p in m.parameters] == ["diffuse_color", "specular_color", "roughness", "clearcoat",
                                              "clearcoat_f0", "clearcoat_roughness"]
    assert all(0 <= p.bounds[0] and p.bounds[1] <= 1 for p in m.parameters)
    R = np.array([0.0, 0.04, 0.5, 0.81])
    np.testing.assert_allclose(((1 - ior_of(R)) / (1 + ior_of(R))) ** 2, R, atol=1e-12)


def test02_eval_is_storms_evaluate_light():
    m = PreviewSurface()
    p = random_params(3)
    wi, wo = cv.direction_pairs()
    f = cv._eval(m, p, wi, wo)
    for t in range(3):
        inputs = {"diffuseColor": p["diffuse_color"][t], "specularColor": p["specular_color"][t],
                  "roughness": p["roughness"][t, 0], "clearcoat": p["clearcoat"][t, 0],
                  "clearcoatRoughness": p["clearcoat_roughness"][t, 0], "ior": ior_of(p["clearcoat_f0"][t, 0])}
        np.testing.assert_allclose(f[t], storm(inputs, wi, wo), rtol=1e-9, atol=1e-12)


def test03_jacobian_matches_finite_differences():
    m = PreviewSurface()
    p = random_params(4, seed=1)
    wi, wo = cv.direction_pairs()
    T = 4
    J = m.jacobian(p, np.broadcast_to(wi, (T,) + wi.shape), np.broadcast_to(wo, (T,) + wo.shape))
    x = m.pack(p)
    h = 1e-6
    for k in range(x.shape[1]):
        xp, xm = x.copy(), x.copy()
        xp[:, k] += h
        xm[:, k] -= h
        num = (cv._eval(m, m.unpack(xp), wi, wo) - cv._eval(m, m.unpack(xm), wi, wo)) / (2 * h)
        np.testing.assert_allclose(J[..., k], num, atol=1e-6 * max(1.0, np.abs(num).max()))


def test04_a_lobe_dim_at_grazing_goes_into_the_clearcoat_and_stays_glossy(reg, ggx):
    """The README demo's texels: a Lafortune lobe (exponent 60) that does not brighten toward grazing.

    The specular workflow's lobe rises to white at grazing, so alone it spreads flat (the USD export's roughness
    was 0.998 at the median); the clearcoat's Fresnel runs from c·R to c, so the gloss survives there.
    """
    laf = reg.create("brdf-model", "lafortune", {"lobes": 1})
    T = 4
    p = {"rho_d": np.full((T, 3), 0.1), "rho_s_1": np.linspace(0.05, 0.3, T)[:, None] * [1.0, 0.9, 0.8],
         "c_xy_1": np.full((T, 1), -1.0), "c_z_1": np.ones((T, 1)), "exponent_1": np.full((T, 1), 60.0)}
    coat = to_preview_surface(laf, p, ggx)
    alone = to_preview_surface(laf, p, ggx, clearcoat=False)
    assert (coat["clearcoat"] > 0).all() and (coat["clearcoat_roughness"] < 0.6).all()
    assert (coat["error"] < alone["error"]).all() and (coat["error"] < cv.FLAG_ERROR).all()
    assert (alone["clearcoat"] == 0).all()
    for k, c in {"diffuse_color": 3, "specular_color": 3, "roughness": 1, "error": 1}.items():
        assert coat[k].shape == (T, c) and np.isfinite(coat[k]).all()


def test05_hard_cases_black_and_nan_texels(ggx):
    p = {"rho_d": np.array([[0.0] * 3, [np.nan] * 3, [0.1] * 3]), "f0": np.array([[0.0] * 3, [0.04] * 3, [0.04] * 3]),
         "alpha": np.array([[0.2], [0.2], [0.2]])}
    r = to_preview_surface(ggx, p, ggx, iterations=2)
    assert all(np.isfinite(v).all() for v in r.values())
    assert r["error"][1, 0] == 1.0  # a texel whose source is not finite lost everything
    assert r["error"][2, 0] < 0.1
