"""The fidelity benchmark's ideal fit: the Fit node's kernel on noise-free truth samples at shared pairs.

The ideal fit stands in the benchmark's table as what a model and its bounds leave with a perfect capture;
these tests check that it is what it says: a model fitted to its own truth scores near zero, and the
pairs really are shared by every texel (the far light and camera positions give each texel the same ω).
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import fidelity  # noqa: E402

from sbrdf_core.geometry import tile_directions  # noqa: E402
from sbrdf_core.registry import default_registry  # noqa: E402


def _truth(tmp_path, kind: str, n: int = 8) -> str:
    name, mp = fidelity.TRUTH[kind]
    url = str(tmp_path / f"truth_{kind}")
    fidelity.write_param_maps(url, default_registry().create("brdf-model", name, mp), mp, fidelity.truth_maps(kind, n))
    return url


def test_a_model_fitted_to_its_own_truth_scores_near_zero(tmp_path):
    url = _truth(tmp_path, "laf")
    s = fidelity.ideal_fit(url, "lafortune", {"lobes": 2}, {"grazing_growth": 0.0, "peak_factor": 0.0,
                                                            "resolve_sharpness": False})
    assert s["rel"].shape == (16, fidelity.PAIRS_RANDOM + fidelity.PAIRS_MIRROR)  # every 2nd texel of 8²
    assert np.isfinite(s["rel"]).all()
    assert np.median(s["rel"]) < 0.02
    assert not s["firefly"].any()


def test_another_model_scores_worse_than_its_own(tmp_path):
    url = _truth(tmp_path, "ct")
    own = fidelity.ideal_fit(url, "cook-torrance", {"distribution": "ggx"})
    laf = fidelity.ideal_fit(url, "lafortune", {"lobes": 1})
    assert np.percentile(laf["rel"], 90) > 2 * np.percentile(own["rel"], 90)


def test_far_positions_give_every_texel_the_same_directions():
    wi, wo = fidelity.scoring_pairs(1, seed=21)
    w_i, _, w_o = tile_directions([64, 64], fidelity.SIZE_MM, (0, 64), (0, 64), wi[0] * 1e9, wo[0] * 1e9)
    assert np.abs(w_i - wi[0][None]).max() < 1e-6
    assert np.abs(w_o - wo[0][None]).max() < 1e-6
