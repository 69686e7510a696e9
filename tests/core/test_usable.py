"""usable's compiled pass gives the NumPy passes' bits: the mask, the zeroed copy and its dtype (float16, which
numba does not compile, through the NumPy passes)."""

from __future__ import annotations

import contextlib

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_core import _compiled
from sbrdf_core.nodes.fit import usable, usable_mask


@contextlib.contextmanager
def compiled_from(elements: int):
    """The size from which compiled passes run, set for a block (these tests' arrays are small)."""
    before, _compiled.MIN_ELEMENTS = _compiled.MIN_ELEMENTS, elements
    try:
        yield
    finally:
        _compiled.MIN_ELEMENTS = before

SPECIAL = np.array([np.nan, np.inf, -np.inf, -0.0, 1e38, 3.0])


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), texels=st.integers(0, 6), samples=st.integers(0, 9),
       channels=st.integers(1, 4), source=st.sampled_from([np.float16, np.float32, np.float64]),
       target=st.sampled_from([None, np.float32, np.float64]), valid_dtype=st.sampled_from([bool, np.uint8]))
def test_usable_compiled_equals_numpy(seed, texels, samples, channels, source, target, valid_dtype):
    rng = np.random.default_rng(seed)
    f_r = rng.normal(size=(texels, samples, channels)).astype(source)
    spots = rng.random(f_r.shape) < 0.3
    with np.errstate(over="ignore"):  # 1e38 is inf in float16: one more non-finite value
        f_r[spots] = rng.choice(SPECIAL, spots.sum()).astype(source)
    valid = (rng.random((texels, samples)) < 0.7).astype(valid_dtype)
    with compiled_from(0):
        got_f, got_v = usable(f_r, valid, target)
    mask = usable_mask(f_r, valid)
    dtype = np.dtype(source if target is None else target)
    ref = np.where(mask[..., None], f_r.astype(dtype), dtype.type(0))
    assert got_v.dtype == bool and np.array_equal(got_v, mask)
    assert got_f.dtype == dtype and got_f.tobytes() == ref.tobytes()
    assert np.isfinite(got_f).all()


def test_usable_of_other_shapes_takes_the_numpy_pass():
    f_r = np.array([[1.0, np.nan], [2.0, 3.0]])  # (T, S) without channels: not the compiled kernel's layout
    out, valid = usable(f_r[..., None], np.ones((2, 2), bool))
    assert out[0, 1, 0] == 0.0 and not valid[0, 1] and valid.sum() == 3
    out, valid = usable(np.ones((2, 3)), np.array([True, False]))  # a texel's samples as channels
    assert out.tolist() == [[1.0] * 3, [0.0] * 3] and valid.tolist() == [True, False]
