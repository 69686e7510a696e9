"""Lafortune's starting exponent scan (compiled) against a plain NumPy least squares of the same problem.

``scan_first_exponent`` picks, per texel, the lobe-1 exponent whose solved (clipped) lobe magnitudes leave
the smallest cost, summing what does not depend on the candidate once.  The reference builds each
candidate's design matrix and solves its (ridged) normal equations: the same choice and magnitudes.
"""

import numpy as np
import pytest

from sbrdf_core.registry import default_registry
from sbrdf_models.lafortune_kernels import scan_first_exponent

LOG_N = np.log(np.array([3.0, 10.0, 40.0, 160.0, 640.0]))


def _directions(rng, shape, below=0.15):
    v = rng.normal(size=shape + (3,))
    v[..., 2] = np.abs(v[..., 2]) - below  # some below the horizon: they only add to the cost
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _reference(model, x, wi, wo, f, w):
    """Per texel and candidate: the cost ``(T, Q)`` and the clipped lobe magnitudes ``(T, Q, lobes, C)``."""
    params = model.unpack(x)
    costs, mags = [], []
    for t in range(x.shape[0]):
        up = (wi[t, :, 2] > 0) & (wo[t, :, 2] > 0) & (w[t] > 0)
        r = (f[t] - params["rho_d"][t]) * w[t][:, None]
        costs.append([])
        mags.append([])
        for ln in LOG_N:
            cols = []
            for j in range(model.lobes):
                cxy = params[f"c_xy_{j + 1}"][t, 0]
                c = np.array([cxy, cxy, 1.0])  # the fit form: C_z = 1, isotropic
                n = np.exp(ln if j == 0 else params[f"log_exponent_{j + 1}"][t, 0])
                dot = (c * wi[t] * wo[t]).sum(axis=-1)
                with np.errstate(all="ignore"):
                    cols.append(np.where(up & (dot > 0), np.exp(np.minimum(n * np.log(np.maximum(dot, 1e-300)), 60.0)), 0.0) * w[t])
            A = np.stack(cols, axis=1)
            # the kernel's ridge (1e-12): a lobe too sharp to touch any sample gets no magnitude
            rho = np.clip(np.linalg.solve(A[up].T @ A[up] + 1e-12 * np.eye(A.shape[1]), A[up].T @ r[up]), 0.0, 1e6)
            cost = ((r[up] - A[up] @ rho) ** 2).sum() + ((f[t][~up & (w[t] > 0)] * w[t][~up & (w[t] > 0), None]) ** 2).sum()
            cost += 1e-12 * (rho ** 2).sum()  # the ridge's term: the kernel scores the ridged problem it solves
            costs[-1].append(cost)
            mags[-1].append(rho)
    return np.array(costs), np.array(mags)


@pytest.mark.parametrize("lobes", [1, 2, 3])  # 3: the general sums (1-2 lobes take one pass)
@pytest.mark.parametrize("seed", [0, 1])
def test_scan_matches_a_plain_least_squares(lobes, seed):
    rng = np.random.default_rng(seed)
    model = default_registry().create("brdf-model", "lafortune", {"lobes": lobes}).fit_form()
    T, S = 40, 80
    wi, wo = _directions(rng, (T, S)), _directions(rng, (T, S))
    params = model.defaults(T)
    params["rho_d"] = rng.random((T, 3)) * 0.1
    if lobes == 3:  # the defaults' lobes 2 and 3 are one shape: their magnitudes would not be determined
        params["c_xy_3"], params["log_exponent_3"] = np.full((T, 1), -0.5), np.full((T, 1), np.log(2.0))
    truth = {k: v.copy() for k, v in params.items()}
    truth["log_exponent_1"] = rng.uniform(1.0, 6.0, (T, 1))
    truth["rho_s_1"] = rng.uniform(0.2, 2.0, (T, 3))
    f = model.to_model(truth)
    f = default_registry().create("brdf-model", "lafortune", {"lobes": lobes}).eval(f, wi, wo)
    f = f + 0.01 * rng.normal(size=(T, S, 3))
    w = (rng.random((T, S)) > 0.1).astype(float)
    x = model.pack(params)
    out = scan_first_exponent(x, LOG_N, wi, wo, f, w, model.lobes, int(model.anisotropic), bool(model.has_beta))
    got = model.unpack(out)
    costs, mags = _reference(model, x, wi, wo, f, w)
    q = np.searchsorted(LOG_N, got["log_exponent_1"][:, 0])
    np.testing.assert_array_equal(LOG_N[q], got["log_exponent_1"][:, 0])  # one of the candidates, exactly
    picked = costs[np.arange(T), q]
    # the cheapest candidate, up to the rounding of its closed-form cost (e0 − 2ρ·h + ρGρ cancels): a spike
    # touching one sample can tie with a broader lobe
    np.testing.assert_array_less(picked, costs.min(axis=1) * (1 + 1e-6) + 1e-12)
    assert (q == costs.argmin(axis=1)).mean() > 0.9
    for j in range(lobes):
        np.testing.assert_allclose(got[f"rho_s_{j + 1}"], mags[np.arange(T), q, j], rtol=1e-6, atol=1e-9)
