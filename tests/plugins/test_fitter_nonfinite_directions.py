"""McAllister's fitters on non-finite directions: finite, in-bounds lobes and a flag, never NaN with flags 0."""

from __future__ import annotations

import numpy as np
import pytest

from sbrdf_core.nodes.fit import NONFINITE_INPUT, NONFINITE_RESULT

from .test_fitters import directions, lafortune_truth


@pytest.mark.parametrize("fitter", ["line-search", "mcallister"])
def test_nan_directions_give_finite_lobes_or_a_flag(registry, fitter):
    model = registry.create("brdf-model", "lafortune", {"lobes": 1})
    T, S = 4, 40
    wi, wo = directions(T, S)
    f = model.eval(lafortune_truth(model, T), wi, wo)
    valid = np.ones((T, S), bool)
    wi[0, :5] = np.nan  # a few broken directions in texel 0
    wi[1] = np.nan  # every direction of texel 1 broken
    wo[2, 3] = np.inf
    res = registry.create("fitter", fitter, {}).fit(model, f, valid, wi, wo)
    x = model.pack(res.params)
    lo, hi = model.bounds()
    assert np.isfinite(x).all() and np.isfinite(res.rms).all()
    assert ((x >= lo - 1e-9) & (x <= hi + 1e-9)).all()
    flags = np.asarray(res.flags)
    assert flags[0] & NONFINITE_INPUT and flags[1] & NONFINITE_INPUT and flags[2] & NONFINITE_INPUT
    assert not flags[3] & (NONFINITE_INPUT | NONFINITE_RESULT)
    assert res.samples[1] == 0 and res.samples[0] == S - 5
