"""tile_directions' compiled pass gives directions_to's NumPy values to an ulp (its bits, where einsum sums as measured)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sbrdf_core import _compiled
from sbrdf_core.geometry import _compiled_directions, directions_to, texel_centres, tile_directions


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), poses=st.integers(1, 40), side=st.integers(1, 9),
       scale=st.sampled_from([1e-6, 1.0, 800.0, 1e9]))
def test_compiled_tile_directions_equal_numpy_to_an_ulp(seed, poses, side, scale):
    rng = np.random.default_rng(seed)
    size = (20.0, 30.0)
    light, camera = rng.normal(0, scale, (poses, 3)), rng.normal(0, scale, (poses, 3))
    p = texel_centres((side, side), size, 0, side, 0, side).reshape(-1, 3)
    light[0] = p[0]  # a light on a texel centre: distance 0, direction +z
    got = _compiled_directions()(p, light, camera)
    wi, r = directions_to(p, light)
    wo, _ = directions_to(p, camera)
    for a, b in zip(got, (wi, r, wo)):
        assert a.shape == b.shape
        np.testing.assert_array_max_ulp(a, b, maxulp=1)
    assert tuple(got[0][0, 0]) == (0.0, 0.0, 1.0)
    with pytest.MonkeyPatch.context() as m:  # every size takes the compiled pass
        m.setattr(_compiled, "MIN_ELEMENTS", 0)
        ref = tile_directions((side, side), size, (0, side), (0, side), light, camera)
    assert all(a.tobytes() == b.tobytes() for a, b in zip(ref, got))


def test_which_pass_runs_depends_on_the_size_not_on_what_is_imported():
    from pathlib import Path

    assert not _compiled.worth_compiling(_compiled.MIN_ELEMENTS - 1)
    assert _compiled.worth_compiling(_compiled.MIN_ELEMENTS)
    core = Path(_compiled.__file__).parent
    assert [f for f in ("geometry.py", "channels.py", "constraints.py") if "sys.modules" in (core / f).read_text()] == []
