"""``sbrdf plot``: the three viewer figures, from a real run (real zarr, real matplotlib)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from sbrdf_core.errors import SbrdfError
from sbrdf_core.plot import Viewer, direction
from sbrdf_core.runner import run_graph

from .conftest import graph_yaml


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("plot")
    g = tmp / "g.yaml"
    g.write_text(graph_yaml(tmp / "s", capture={"poses": 40, "texels": [16, 12]}, fit={"model": "lambert"}))
    run_graph(str(g))
    return tmp / "s"


def test_sbrdf_plot_writes_three_nontrivial_figures(store, tmp_path):
    import matplotlib.image as mpimg

    out = subprocess.run([sys.executable, "-m", "sbrdf_core.cli", "plot", str(store / "reflectance"), "--params",
                          str(store / "fit"), "--out", str(tmp_path / "p"), "--texel", "3", "4", "--wi", "35", "20"],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    for name in ("spatial.png", "hemisphere.png", "incidence-plane.png"):
        path = tmp_path / "p" / name
        assert str(path) in out.stdout
        img = mpimg.imread(path)
        assert img.shape[0] > 300 and img.shape[1] > 400
        assert img[..., :3].std() > 0.05  # not a blank canvas
        assert len(np.unique((img[..., :3] * 255).astype(np.uint8).reshape(-1, 3), axis=0)) > 50


def test_spatial_view_picks_the_nearest_pose_per_texel(store):
    view = Viewer(str(store / "reflectance"))
    wi, wo = direction(30, 0), direction(30, 180)
    img, dist = view.spatial(wi, wo, rows=5)  # row bands that do not divide the grid
    V, U = img.shape[:2]
    assert (U, V) == view.texels and np.isfinite(dist).all()
    # Brute force for one texel.
    wis, wos, f, ok = view.texel_samples(7, 9)
    d = np.arccos(np.clip(wis @ wi, -1, 1)) + np.arccos(np.clip(wos @ wo, -1, 1))
    d[~ok] = np.inf
    np.testing.assert_allclose(img[9, 7], f[np.argmin(d)])
    assert dist[9, 7] == pytest.approx(d.min())


def test_plot_errors_name_the_problem(store, tmp_path):
    view = Viewer(str(store / "reflectance"))
    with pytest.raises(SbrdfError, match=r"texel \(99, 0\) is outside the 16x12 grid"):
        view.texel_samples(99, 0)
    with pytest.raises(SbrdfError, match="holds a ParamMaps, expected SampledReflectance"):
        Viewer(str(store / "fit"))
