"""Variable projection (``separable_fit``): the same fits as the general LM, inside the same bounds."""

from __future__ import annotations

import numpy as np
import pytest

from sbrdf_core.constraints import Limits
from sbrdf_lib.lm import fit_model
from sbrdf_models.lafortune import LafortuneFitForm
from sbrdf_models.lambert import LambertModel

from .test_fitters import data, directions


def general(monkeypatch, cls):
    """Run the general LM: the form's ``separable_fit`` hidden."""
    monkeypatch.setattr(cls, "separable_fit", None)


@pytest.mark.parametrize("lobes", [1, 2])
def test_separable_fit_is_as_good_as_the_general_lm(registry, monkeypatch, lobes):
    model = registry.create("brdf-model", "lafortune", {"lobes": lobes})
    _, f, valid, wi, wo = data(model, T=40, noise=0.01, seed=3)
    _, conv_fast, cost_fast = fit_model(model, f, valid, wi, wo, separable=True)
    general(monkeypatch, LafortuneFitForm)
    _, _, cost_general = fit_model(model, f, valid, wi, wo)
    assert conv_fast.all()
    assert cost_fast.mean() <= 1.001 * cost_general.mean()
    assert (cost_fast <= 1.05 * cost_general).mean() >= 0.95


def test_separable_fit_stays_inside_the_bounds(registry):
    """Grazing growth 1 means |C_xy| ≤ C_z = 1; the sharpness bound caps n; magnitudes are never negative."""
    model = registry.create("brdf-model", "lafortune", {"lobes": 2})
    truth, f, valid, wi, wo = data(model, T=30, noise=0.02, seed=5)
    for j in (1, 2):  # a truth that grows toward grazing: the fit must not follow it there
        truth[f"c_xy_{j}"] = truth[f"c_xy_{j}"] * 1.3
    f = model.eval(truth, wi, wo)
    limits = Limits(peak=None, resolution=np.full(30, 0.1), growth=1.0, albedo=None)
    params, _, cost = fit_model(model, f, valid, wi, wo, limits=limits, separable=True)
    cap = float(np.asarray(limits.max_cosine_exponent()).max())
    for j in (1, 2):
        assert (np.abs(params[f"c_xy_{j}"]) <= params[f"c_z_{j}"] + 1e-9).all()
        assert (params[f"exponent_{j}"] <= cap * (1 + 1e-9)).all()
        assert (params[f"rho_s_{j}"] >= 0).all()
    assert np.isfinite(cost).all()


def test_separable_fit_handles_empty_and_dark_texels(registry):
    """No valid sample, all-zero data and samples below the horizon: finite, converged, magnitudes 0."""
    model = registry.create("brdf-model", "lafortune", {"lobes": 2})
    wi, wo = directions(3, 50, seed=2)
    f = np.zeros((3, 50, 3))
    valid = np.ones((3, 50), bool)
    valid[0] = False
    wi[2, :, 2] = -np.abs(wi[2, :, 2])
    f[2] = 0.3
    params, converged, cost = fit_model(model, f, valid, wi, wo, separable=True)
    assert converged.all() and np.isfinite(cost).all()
    assert all(np.isfinite(v).all() for v in params.values())
    assert np.allclose(params["rho_d"], 0.0)
    assert cost[2] == pytest.approx(50 * 3 * 0.09)  # below the horizon the model is 0: every sample is residual


def test_lambert_closed_form_equals_the_general_lm(registry, monkeypatch):
    model = registry.create("brdf-model", "lambert")
    wi, wo = directions(20, 40, seed=4)
    rng = np.random.default_rng(4)
    f = rng.uniform(0.0, 0.4, (20, 40, 3))
    valid = rng.random((20, 40)) > 0.2
    wi[0, :5, 2] = -0.1  # a few samples below the horizon
    fast, _, cost_fast = fit_model(model, f, valid, wi, wo)
    general(monkeypatch, LambertModel)
    slow, _, cost_slow = fit_model(model, f, valid, wi, wo, iterations=200, tolerance=1e-12)
    np.testing.assert_allclose(fast["rho_d"], slow["rho_d"], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(cost_fast, cost_slow, rtol=1e-6)


def test_variable_projection_is_opt_in_for_lafortune(registry, monkeypatch):
    """Lafortune's result comes from the general LM unless variable_projection asks otherwise: ``start: separable``
    only starts from the separable fit, then minimises lm's own weighted objective from there; by default it is
    not run at all."""
    calls = []
    original = LafortuneFitForm.separable_fit
    monkeypatch.setattr(LafortuneFitForm, "separable_fit", lambda self, *a, **k: calls.append(1) or original(self, *a, **k))
    model = registry.create("brdf-model", "lafortune", {"lobes": 1})
    _, f, valid, wi, wo = data(model, T=8, noise=0.01, seed=1)
    fit_model(model, f, valid, wi, wo)
    registry.create("fitter", "lm", {"model": "lafortune"}).fit(model, f, valid, wi, wo)
    assert calls == []
    started = registry.create("fitter", "lm", {"model": "lafortune", "start": "separable"}).fit(model, f, valid, wi, wo)
    assert calls == [1]
    vp = registry.create("fitter", "lm", {"model": "lafortune", "variable_projection": True}).fit(model, f, valid, wi, wo)
    assert calls == [1, 1]
    assert not np.allclose(started.params["rho_d"], vp.params["rho_d"], rtol=1e-6, atol=0)
