"""``sbrdf plot``: the three viewer figures, from a real run (real zarr, real matplotlib)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from sbrdf_core.errors import SbrdfError
from sbrdf_core.runner import run_graph
from sbrdf_viewer.plot import (
    MIN_SAMPLES,
    Viewer,
    choose_views,
    direction,
    hemisphere_figure,
    incidence_figure,
    plot_views,
    spatial_figure,
)

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


@pytest.fixture(scope="module")
def viewer(store):
    return Viewer(str(store / "reflectance"), str(store / "fit"))


def test_default_views_show_samples_where_the_old_fixed_directions_showed_none(viewer):
    """The capture's 40 poses avoid (30°, 0°): the old fixed default showed an empty incidence plane and a
    spatial image 45° from any pose.  The defaults now come from the texel's own samples."""
    u, v = 8, 6
    old = choose_views(viewer, u, v, wi=(30.0, 0.0), wo=(30.0, 180.0), tol_deg=15.0)
    assert old.in_plane.sum() == 0 and "no sample within 15° of the incidence plane" in old.notes
    _, old_dist = viewer.spatial(old.wi, old.wo)
    assert np.degrees(np.median(old_dist)) > 30

    c = choose_views(viewer, u, v)
    assert c.in_plane.sum() >= MIN_SAMPLES and c.near.sum() >= c.in_plane.sum()
    assert 15.0 <= c.tol_deg <= 45.0
    if c.tol_deg > 15.0:
        assert any("tolerance widened" in n for n in c.notes)
    wis, wos, f, ok = viewer.texel_samples(u, v)
    pose = int(np.argmin(np.where(ok, np.arccos(np.clip(wis @ c.wi, -1, 1)), np.inf)))
    np.testing.assert_allclose(c.wi, wis[pose])  # a measured incident direction
    np.testing.assert_allclose(c.wo, wos[pose])  # and the spatial image's ω_r of that same pose
    _, dist = viewer.spatial(c.wi, c.wo)
    assert dist[v, u] == pytest.approx(0, abs=1e-6) and np.degrees(np.median(dist)) < 15
    # given directions are kept; an ω_r left out comes from the pose nearest the given ω_i
    g = choose_views(viewer, u, v, wi=(35.0, 20.0))
    assert g.wi_deg == (35.0, 20.0) and g.wi_from == "given" and g.wo_from != "given"
    np.testing.assert_allclose(g.wi, direction(35, 20))


def test_incidence_plane_and_hemisphere_axes_are_scaled_to_the_samples(viewer):
    """The data sit near 0.06 sr⁻¹ (a Lambertian ρ_d/π): no axis fixed at 0–1."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = choose_views(viewer, 8, 6)
    data = c.lum[c.in_plane]
    assert data.size and data.max() < 0.5
    fig = incidence_figure(viewer, c)
    ax = fig.axes[0]
    assert data.max() <= ax.get_ylim()[1] <= 1.25 * data.max()
    assert f"{data.size} samples within {c.tol_deg:g}°" in ax.get_title()
    plt.close(fig)

    fig = hemisphere_figure(viewer, c)
    lo, hi = fig.axes[0].collections[0].get_clim()
    shown = c.lum[c.near]
    assert np.percentile(shown, 50) <= hi <= 1.05 * shown.max() and lo <= shown.min()
    plt.close(fig)


def test_views_say_so_when_nothing_is_near_the_given_directions(viewer):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = choose_views(viewer, 8, 6, wi=(85.0, 45.0), wo=(85.0, -135.0), tol_deg=2.0)  # grazing: no pose there
    assert c.tol_deg == 2.0 and c.near.sum() == 0  # a given tolerance is not widened
    assert any(n.startswith("no sample within 2° of ω_i: the nearest is") for n in c.notes)
    for draw in (hemisphere_figure, incidence_figure):
        fig = draw(viewer, c)
        assert "no sample within 2° of ω_i" in fig.axes[0].get_title()
        if draw is incidence_figure:
            assert fig.axes[0].get_ylim()[1] > 0  # scaled to the model / the texel's samples, not left at 0
        plt.close(fig)
    fig = spatial_figure(viewer, c)
    assert "NO POSE NEAR these directions" in fig.axes[0].get_title()
    plt.close(fig)


def test_plot_views_with_no_directions_writes_every_figure(store, tmp_path):
    paths = plot_views(str(store / "reflectance"), tmp_path / "p", params_url=str(store / "fit"))
    assert [p.name for p in paths] == ["spatial.png", "hemisphere.png", "incidence-plane.png", "fit-error.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_sbrdf_plot_without_the_plot_extra_names_its_install_command(tmp_path):
    """A plain install has no matplotlib: ``sbrdf plot`` says which extra to install, in one line, no traceback."""
    block = ("import sys; sys.modules['matplotlib'] = None; from sbrdf_core.cli import main; "
             "sys.exit(main(sys.argv[1:]))")
    proc = subprocess.run([sys.executable, "-c", block, "plot", str(tmp_path / "missing"), "--out", str(tmp_path / "p")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "sbrdf: error: sbrdf plot needs the optional dependency 'matplotlib', which is not installed: "
        "pip install 'sbrdf[plot]'"], proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "p").exists()
