"""Spatial coherence of the Fit node: neighbours' solutions as restarts, outliers flagged (sbrdf_core.coherence)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sbrdf_core.coherence import OFFSETS, ring
from sbrdf_core.geometry import fibonacci_hemisphere, tile_directions
from sbrdf_core.nodes.fit import EXTRA, OUTLIER, FitOptions, fit_tile

GRID = (5, 5)
SIZE = (10.0, 10.0)
CENTRE = 12
TRUTH = {"rho_d": [0.05, 0.06, 0.07], "rho_s_1": [0.6, 0.55, 0.5], "c_xy_1": [-1.0], "c_z_1": [1.0],
         "exponent_1": [60.0]}


def test_ring_moves_each_row_to_its_texel():
    x = np.arange(12.0).reshape(12, 1)  # a 3 x 4 grid
    around = ring(x, (3, 4), fill=np.nan)
    right = around[OFFSETS.index((0, 1))].reshape(3, 4)
    assert right[0, 0] == 1 and right[2, 2] == 11 and np.isnan(right[:, 3]).all()
    up_left = around[OFFSETS.index((-1, -1))].reshape(3, 4)
    assert up_left[1, 1] == 0 and up_left[2, 3] == 6 and np.isnan(up_left[0]).all() and np.isnan(up_left[:, 0]).all()


def _tile(model, params, noise=0.002, seed=0):
    light = fibonacci_hemisphere(60, 75) * 400
    camera = fibonacci_hemisphere(60, 60, offset=2.0) * 600
    wi, _, wo = tile_directions(GRID, SIZE, (0, GRID[0]), (0, GRID[1]), light, camera)
    f = model.eval(params, wi, wo)
    f = f + noise * np.random.default_rng(seed).standard_normal(f.shape)
    V, U = GRID
    return f.reshape(V, U, -1, 3), np.ones((V, U, f.shape[1], 1), bool), light, camera


class Trapped:
    """``lm``, except that its own fit of the centre texel is a broad lobe: a texel caught in a worse minimum."""

    def __init__(self, lm):
        self.lm, self.model_name, self.model_config = lm, lm.model_name, lm.model_config
        self.starts_given = 0

    def fit(self, model, f_r, valid, wi, wo, *, limits=None, rms=True, usable=False, initial=None):
        res = self.lm.fit(model, f_r, valid, wi, wo, limits=limits, rms=rms, usable=usable, initial=initial)
        if initial is None and f_r.shape[0] == GRID[0] * GRID[1]:
            res.params["exponent_1"][CENTRE] = 3.0
            res.params["rho_s_1"][CENTRE] = 0.05
        else:
            self.starts_given += f_r.shape[0]
        return res


def _fit(fitter, model, data, **options):
    f, valid, light, camera = data
    info = [{"array-location": [(0, GRID[0]), (0, GRID[1]), (0, f.shape[2]), (0, 3)]}]
    out = fit_tile(f, valid, light, camera, GRID, SIZE, fitter, model, FitOptions(holdout=0.0, **options),
                   block_info=info).reshape(GRID[0] * GRID[1], -1)
    K = model.size
    params = model.unpack(out[:, :K].astype(np.float64))
    column = {name: out[:, K + i] for i, name in enumerate(EXTRA)}
    return params, column


@pytest.fixture
def uniform(registry):
    model = registry.create("brdf-model", "lafortune", {"lobes": 1})
    T = GRID[0] * GRID[1]
    truth = {k: np.tile(np.asarray(v, np.float64), (T, 1)) for k, v in TRUTH.items()}
    lm = registry.create("fitter", "lm", {"model": "lafortune"})
    return model, truth, lm


def test_a_texel_in_a_worse_minimum_is_refitted_from_its_neighbours(uniform):
    model, truth, lm = uniform
    data = _tile(model, truth)
    alone, col_alone = _fit(Trapped(lm), model, data, coherence="none")
    assert alone["exponent_1"][CENTRE, 0] < 10  # the speck, left as the fitter made it
    untrapped, col_untrapped = _fit(lm, model, data, coherence="none")
    trapped = Trapped(lm)
    params, column = _fit(trapped, model, data)
    assert trapped.starts_given >= 1  # refined from a neighbour's solution, through the fitter's `initial`
    assert column["from_neighbour"][CENTRE] == 1
    assert column["rms"][CENTRE] < 0.5 * col_alone["rms"][CENTRE]
    # as good a fit of its own samples as an untrapped start finds, within the noise ...
    assert column["rms"][CENTRE] == pytest.approx(col_untrapped["rms"][CENTRE], rel=0.03)
    # ... and, of the fits that good, the one like its neighbours': its own samples leave the exponent loose
    # (an untrapped start finds about 44 where every neighbour has about 59)
    others = np.delete(params["exponent_1"][:, 0], CENTRE)
    assert untrapped["exponent_1"][CENTRE, 0] < 0.8 * np.median(others)
    assert params["exponent_1"][CENTRE, 0] == pytest.approx(np.median(others), rel=0.05)
    assert not (column["flags"].astype(int) & OUTLIER).any()


def test_a_texel_of_another_material_is_kept_and_flagged_an_outlier(uniform):
    model, truth, lm = uniform
    other = {k: v.copy() for k, v in truth.items()}
    other["exponent_1"][CENTRE], other["rho_s_1"][CENTRE] = 4.0, 0.08  # a single texel of a matte material
    params, column = _fit(lm, model, _tile(model, other))
    assert params["exponent_1"][CENTRE, 0] < 10  # its own samples say matte: no neighbour fits them better
    assert column["from_neighbour"][CENTRE] == 0
    flagged = np.flatnonzero(column["flags"].astype(int) & OUTLIER)
    assert flagged.tolist() == [CENTRE]


def test_training_error_rises_at_most_within_the_noise(uniform):
    """Coherence changes a texel to a lower training cost (the node's own RMS), or, for an ambiguous texel, to
    one at most a parameter's worth of its residual variance per parameter above its own."""
    model, truth, lm = uniform
    rng = np.random.default_rng(4)
    varied = {k: v * rng.uniform(0.7, 1.3, v.shape) if k in ("rho_s_1", "exponent_1") else v
              for k, v in truth.items()}
    data = _tile(model, varied, noise=0.01, seed=2)
    _, alone = _fit(lm, model, data, coherence="none")
    _, coherent = _fit(lm, model, data)
    S, K = data[0].shape[2], model.size
    allowance = 1 + K / (3 * S - K)
    assert (coherent["rms"] ** 2 <= alone["rms"] ** 2 * allowance * (1 + 1e-5)).all()


def test_specks_finds_a_lone_bright_texel_not_an_edge_or_noise():
    from sbrdf_core.coherence import specks

    rng = np.random.default_rng(0)
    image = 1.0 + 0.002 * rng.standard_normal((12, 12))
    image[:, 6:] = 3.0  # a second region: its edge is no speck
    image[3, 3] = 1.5  # a speck
    found = specks(image)
    assert found[3, 3] and found.sum() == 1
    region = np.zeros((12, 12), bool)
    region[:, 6:] = True
    assert not specks(image, uniform=region).any()  # only the second region judged
    image[8, 8] = np.nan
    assert specks(image, uniform=region)[8, 8]


class AllTrapped(Trapped):
    """``lm``, except that its own fit of every texel of the tile is a broad lobe: a region caught in one worse
    minimum, which no neighbour can lead out of."""

    def fit(self, model, f_r, valid, wi, wo, *, limits=None, rms=True, usable=False, initial=None):
        res = self.lm.fit(model, f_r, valid, wi, wo, limits=limits, rms=rms, usable=usable, initial=initial)
        if initial is None and f_r.shape[0] == GRID[0] * GRID[1]:
            res.params["exponent_1"][:] = 3.0
            res.params["rho_s_1"][:] = 0.05
        return res


def test_the_pyramid_leads_a_trapped_region_out_from_its_average(uniform):
    model, truth, lm = uniform
    data = _tile(model, truth)
    stuck, _ = _fit(AllTrapped(lm), model, data)  # neighbours alone: every one is as trapped
    assert (stuck["exponent_1"] < 10).all()
    params, column = _fit(AllTrapped(lm), model, data, coherence="pyramid")
    assert (column["from_neighbour"] == 1).all()
    np.testing.assert_allclose(params["exponent_1"], 60.0, rtol=0.35)


@pytest.mark.slow
def test_the_demo_preview_loses_most_of_its_specks(tmp_path):
    """The README demo's preview, fitted with and without coherence: the specks a user saw (texels departing
    from their 3×3 neighbourhood by more than 4× its spread) drop to under a quarter, and the bright ones (over
    20 % above the neighbourhood) to under a fifth."""
    import shutil

    from scipy.ndimage import median_filter

    from sbrdf_core.coherence import specks
    from sbrdf_core.graph import load_graph
    from sbrdf_core.runner import Runner
    from sbrdf_core.store import open_artifact

    root = Path(__file__).resolve().parents[2]
    text = (root / "graphs" / "demo.yaml").read_text()
    counts = {}
    for mode in ("neighbours", "none"):
        graphs = tmp_path / mode / "graphs"
        graphs.mkdir(parents=True)
        (graphs / "demo.yaml").write_text(text.replace("model_params: {lobes: 1}}\n  quantize",
                                                       f"model_params: {{lobes: 1}}, coherence: {mode}}}\n  quantize"))
        assert f"coherence: {mode}" in (graphs / "demo.yaml").read_text()
        shutil.copytree(root / "scenes", tmp_path / mode / "scenes")
        runner = Runner(progress=False)
        runner.run(load_graph(str(graphs / "demo.yaml"), runner.registry, store=str(tmp_path / mode / "runs")),
                   only=["render"])
        image = np.asarray(open_artifact(str(tmp_path / mode / "runs" / "render")).read("image"), np.float64)
        lum = image.sum(axis=-1)
        bright = (lum - median_filter(lum, 3)) > 0.2 * median_filter(lum, 3)
        found = specks(image)
        counts[mode] = (int(found.sum()), int((found & bright).sum()))
    assert counts["neighbours"][0] < 0.25 * counts["none"][0], counts
    assert counts["neighbours"][1] < 0.2 * counts["none"][1], counts


def test_a_fitter_without_initial_is_told_apart(uniform):
    """A fitter written before the contract's ``initial`` keyword: the Fit node turns coherence off for it (with a
    warning) instead of failing at its first refit."""
    from sbrdf_core.nodes.fit import takes_initial

    class Old:
        def fit(self, model, f_r, valid, wi, wo, *, limits=None, rms=True, usable=False):
            raise AssertionError("not called")

    class Open:
        def fit(self, model, f_r, valid, wi, wo, **options):
            raise AssertionError("not called")

    _, _, lm = uniform
    assert takes_initial(lm) and takes_initial(Open()) and not takes_initial(Old())


# -- coherence: basis (basis materials per tile, in the manner of Lensch et al. 2003) ------------------------------

MATTE = {"rho_d": [0.3, 0.2, 0.1], "rho_s_1": [0.08, 0.08, 0.08], "c_xy_1": [-1.0], "c_z_1": [1.0],
         "exponent_1": [5.0]}


def _two_materials(truth):
    """``truth`` with the columns u ≥ 2 of the grid made a matte material, and the mask of those texels."""
    right = (np.arange(GRID[0] * GRID[1]) % GRID[1]) >= 2
    return {k: np.where(right[:, None], np.asarray(MATTE[k], np.float64), v) for k, v in truth.items()}, right


def test_basis_labels_separate_two_materials(uniform):
    model, truth, lm = uniform
    varied, right = _two_materials(truth)
    data = _tile(model, varied, noise=0.005, seed=1)
    _, chosen = _fit(lm, model, data, coherence="basis", materials=0)  # as many as keep paying: two
    label = chosen["material"].astype(int)
    assert set(label[right]) != set(label[~right]) and len(set(label[right])) == len(set(label[~right])) == 1
    _, four = _fit(lm, model, data, coherence="basis")  # the default 4: a material may split, never two merge
    label = four["material"].astype(int)
    assert not set(label[right]) & set(label[~right])


def test_basis_never_raises_a_texels_training_cost(uniform):
    """Against ``coherence: none``: the basis step keeps a texel's own solution unless another fits its training
    samples strictly better, and the neighbours pass after it does the same without its ambiguous-texel step
    (``outlier_distance: 0``); with it, a rise stays within the noise allowance of
    :func:`test_training_error_rises_at_most_within_the_noise`."""
    model, truth, lm = uniform
    rng = np.random.default_rng(4)
    varied = {k: v * rng.uniform(0.7, 1.3, v.shape) if k in ("rho_s_1", "exponent_1") else v
              for k, v in _two_materials(truth)[0].items()}
    data = _tile(model, varied, noise=0.01, seed=2)
    _, alone = _fit(lm, model, data, coherence="none")
    _, strict = _fit(lm, model, data, coherence="basis", outlier_distance=0.0)
    assert (strict["rms"] ** 2 <= alone["rms"] ** 2 * (1 + 1e-5)).all()
    assert strict["from_neighbour"].any()  # the basis changed texels, and none for the worse
    _, basis = _fit(lm, model, data, coherence="basis")
    S, K = data[0].shape[2], model.size
    assert (basis["rms"] ** 2 <= alone["rms"] ** 2 * (1 + K / (3 * S - K)) * (1 + 1e-5)).all()


def _spatial_cv(model, params) -> float:
    """Median over :data:`~sbrdf_core.coherence.APPEARANCE_PAIRS` of the coefficient of variation of f_r (channels
    summed) across the texels: how much a uniform region's fit varies where it is looked at."""
    from sbrdf_core.coherence import appearance

    look = appearance(model, model.pack(params)).sum(axis=-1)
    return float(np.median(look.std(axis=0) / look.mean(axis=0)))


def test_basis_varies_no_more_than_neighbours_on_a_noisy_uniform_region(uniform):
    model, truth, lm = uniform
    data = _tile(model, truth, noise=0.03, seed=5)
    cv = {mode: _spatial_cv(model, _fit(lm, model, data, coherence=mode)[0])
          for mode in ("none", "neighbours", "basis")}
    assert cv["basis"] <= cv["neighbours"] * 1.02, cv


def test_basis_is_deterministic(uniform):
    model, truth, lm = uniform
    data = _tile(model, _two_materials(truth)[0], noise=0.01, seed=3)
    first, second = (np.concatenate([np.concatenate(list(p.values()), axis=1),
                                     np.stack([c[k] for k in EXTRA if k != "fit_time_s"], axis=1)], axis=1)
                     for p, c in (_fit(lm, model, data, coherence="basis") for _ in range(2)))
    np.testing.assert_array_equal(first, second)


def test_materials_out_of_bounds_is_refused_with_its_name(write_graph, registry, tmp_path):
    from sbrdf_core.basis import MAX_MATERIALS
    from sbrdf_core.errors import GraphError
    from sbrdf_core.graph import load_graph

    from ..conftest import graph_yaml

    path = write_graph(graph_yaml(tmp_path / "s", fit={"model": "lambert", "coherence": "basis",
                                                       "materials": MAX_MATERIALS + 1}))
    with pytest.raises(GraphError, match="materials"):
        load_graph(path, registry)
    path = write_graph(graph_yaml(tmp_path / "s", fit={"model": "lambert", "coherence": "clusters"}))
    with pytest.raises(GraphError, match="coherence.*basis"):  # the choices listed come from the declaration
        load_graph(path, registry)


def test_basis_writes_the_material_map_and_counts_it(write_graph, registry, tmp_path):
    from sbrdf_core.graph import load_graph
    from sbrdf_core.runner import Runner
    from sbrdf_core.store import open_artifact

    from ..conftest import graph_yaml

    graph = load_graph(write_graph(graph_yaml(tmp_path / "s", fit={"model": "lambert", "coherence": "basis",
                                                                     "materials": 2})), registry)
    Runner(registry, progress=False).run(graph, only=["fit"])
    art = open_artifact(graph.url("fit"))
    label = np.asarray(art.read("material"))
    assert label.dtype == np.uint8 and label.shape == tuple(art.read("rms").shape)
    fitted = np.asarray(art.read("samples")) > 0
    assert (label[fitted] < 2).all() and (label[~fitted] == 255).all()
    assert art.attrs["summary"]["materials"] == int(label[fitted].max()) + 1
    assert json.dumps(art.attrs["summary"]).startswith('{"materials"')  # in what `sbrdf info` prints of it

    from sbrdf_viewer.plot import error_maps  # `sbrdf plot` shows the map beside the flags

    assert error_maps(art, tmp_path / "fit-error.png").stat().st_size > 0
