"""The channel reductions give NumPy's own reductions bit for bit (NaN as NaN), inf and signed zeros included."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from sbrdf_core import _compiled
from sbrdf_core.channels import abs_channel_mean, all_finite, channel_max, channel_mean

SPECIAL = st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -0.0, 3e38, -3e38, 1.4e-45])  # all fit in float32
ARRAYS = hnp.arrays(
    st.sampled_from([np.float32, np.float64]),
    hnp.array_shapes(min_dims=1, max_dims=4, max_side=5).map(lambda s: s[:-1] + (3,) if len(s) > 1 else (3,)),
    elements=st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32), SPECIAL),
)


@pytest.fixture(autouse=True, scope="module")
def compiled_at_every_size():
    """abs_channel_mean takes its compiled pass on these small arrays too, so both passes are compared."""
    with pytest.MonkeyPatch.context() as m:
        m.setattr(_compiled, "MIN_ELEMENTS", 0)
        yield


@settings(max_examples=200, deadline=None)
@given(ARRAYS)
def test_equal_to_numpys_reductions(a):
    assert np.array_equal(all_finite(a), np.isfinite(a).all(axis=-1))
    with np.errstate(all="ignore"):
        want_max, want_mean = a.max(axis=-1), a.mean(axis=-1)
        got_max, got_mean = channel_max(a), channel_mean(a)
    assert got_max.dtype == want_max.dtype and got_mean.dtype == want_mean.dtype
    # Bit for bit: NaN where NumPy gives NaN, the same sign of zero, the same rounding of the mean.
    nan = np.isnan(want_max)
    assert np.array_equal(np.isnan(got_max), nan)
    assert got_max[~nan].tobytes() == want_max[~nan].tobytes()
    nan = np.isnan(want_mean)
    assert np.array_equal(np.isnan(got_mean), nan)
    assert got_mean[~nan].tobytes() == want_mean[~nan].tobytes()


def test_inputs_are_not_changed_and_no_channels_is_all_finite():
    a = np.array([[1.0, np.nan, 3.0], [4.0, 5.0, 6.0]])
    before = a.copy()
    assert channel_max(a)[1] == 6.0 and np.isnan(channel_max(a)[0])
    assert channel_mean(a)[1] == 5.0
    assert np.array_equal(a, before, equal_nan=True)
    assert all_finite(np.zeros((4, 0))).tolist() == [True] * 4


@settings(max_examples=100, deadline=None)
@given(ARRAYS.filter(lambda a: a.ndim == 3))
def test_abs_channel_mean_is_the_mean_of_the_absolute_values(a):
    """The compiled pass (float64) and the NumPy one (float32) give ``channel_mean(np.abs(a))``'s bits."""
    with np.errstate(all="ignore"):
        for x in (a.astype(np.float64), a.astype(np.float32)):
            want, got = channel_mean(np.abs(x)), abs_channel_mean(x)
            assert got.dtype == want.dtype and got.shape == want.shape
            nan = np.isnan(want)
            assert np.array_equal(np.isnan(got), nan)
            assert got[~nan].tobytes() == want[~nan].tobytes()
