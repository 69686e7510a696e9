"""``sbrdf plot``: McAllister's SBRDF viewer (seed 000 §3.7) as three matplotlib figures.

A command of the viewer plugin (:class:`sbrdf_viewer.command.PlotCommand`), like ``sbrdf view``.

Sampled reflectance is scattered over a 4D domain per texel, so the thesis
looks at it through three linked views, reproduced here as PNG files:

(a) **spatial image** for a chosen (ω_i, ω_r): every texel shows the sample of
    its nearest pose under the bi-angular metric ∠(ω_i, ω_i*) + ∠(ω_r, ω_r*)
    (a Voronoi lookup in 4D, per texel because directions differ across the
    sample);
(b) **exitant hemisphere** of one texel for a chosen ω_i: the samples whose
    incident direction is within ``tol`` of ω_i, at their ω_r on the unit disk
    (x = sin θ cos φ, y = sin θ sin φ), coloured by luminance;
(c) **incidence-plane polar plot** of the same texel and ω_i: the samples whose
    ω_r lies within ``tol`` of the plane through ω_i and the normal, by signed
    θ_r (positive on the far side from the light: forward scattering).

With a ParamMaps artifact the fitted model (created with the registry from its
``model`` / ``model_config`` attributes) is drawn under the samples: an image
in (b), a curve in (c).  Nearby samples are off-plane, so the views look
noisier than the 4D data are (the thesis says the same).

Directions and tolerance the user leaves out are chosen from the data
(:func:`choose_views`): an incident direction the texel was measured under
whose incidence plane holds samples, the exitant direction of that pose, and a
tolerance widened (and said so in the titles) where too few samples are near.
Radial and colour axes span the samples shown.

The spatial image reads the texel grid a band of rows at a time (every pose of
those rows), so plotting a multi-GB scan does not load it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_core.geometry import directions_to, polar_direction, texel_centres

if TYPE_CHECKING:
    from sbrdf_core.contracts import BRDFModel
    from sbrdf_core.store import Artifact

LUMA = np.array([0.2126, 0.7152, 0.0722])  # linear sRGB / Rec. 709 luminance weights


def direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    return polar_direction(np.radians(theta_deg), np.radians(phi_deg))


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0))


class Viewer:
    """Reads one SampledReflectance (and optionally a ParamMaps) and draws the three views."""

    def __init__(self, samples_url: str, params_url: str | None = None, registry=None):
        from sbrdf_core.store import open_artifact

        self.art = open_artifact(samples_url, kind="SampledReflectance")
        n_u, n_v = (int(x) for x in self.art.attrs["texels"])
        size_x, size_y = (float(x) for x in self.art.attrs["size_mm"])
        self.texels: tuple[int, int] = (n_u, n_v)  # (U, V)
        self.size_mm: tuple[float, float] = (size_x, size_y)
        self.light = self.art.read("light_pos")
        self.camera = self.art.read("camera_pos")
        self.f_r = self.art.zarr_array("f_r")
        self.valid = self.art.zarr_array("valid")
        #: The fitted model and its parameter maps (both or neither).
        self.model: BRDFModel | None = None
        self.maps: Artifact | None = None
        if params_url:
            pm = open_artifact(params_url, kind="ParamMaps")
            from sbrdf_core.registry import default_registry

            reg = registry or default_registry()
            self.model = reg.create("brdf-model", pm.attrs["model"], dict(pm.attrs.get("model_config", {})))
            self.maps = pm
            shape = pm.zarr_array(f"params/{self.model.parameters[0].name}").shape[:2]
            if shape != (self.texels[1], self.texels[0]):
                raise SbrdfError(f"{params_url}: parameter maps are {shape[1]}x{shape[0]} texels but {samples_url} "
                                 f"holds {self.texels[0]}x{self.texels[1]}")

    # -- data ----------------------------------------------------------------------------

    def texel_samples(self, u: int, v: int):
        U, V = self.texels
        if not (0 <= u < U and 0 <= v < V):
            raise SbrdfError(f"texel ({u}, {v}) is outside the {U}x{V} grid of {self.art.url}")
        p = texel_centres(self.texels, self.size_mm, v, v + 1, u, u + 1).reshape(1, 3)
        wi, _ = directions_to(p, self.light)
        wo, _ = directions_to(p, self.camera)
        return wi[0], wo[0], np.asarray(self.f_r[v, u]), np.asarray(self.valid[v, u])

    def model_eval(self, u: int, v: int, wi: np.ndarray, wo: np.ndarray) -> np.ndarray | None:
        """The fitted model at texel (u, v) for direction pairs ``(S, 3)`` -> ``(S, 3)``."""
        if self.model is None:
            return None
        assert self.maps is not None, "the model comes with its parameter maps"
        params = {p.name: np.asarray(self.maps.zarr_array(f"params/{p.name}")[v, u], np.float64).reshape(1, -1)
                  for p in self.model.parameters}
        wi = np.broadcast_to(wi, wo.shape)
        return np.asarray(self.model.eval(params, wi[None], wo[None]))[0]

    def spatial(self, wi_star: np.ndarray, wo_star: np.ndarray, rows: int = 32) -> tuple[np.ndarray, np.ndarray]:
        """(a): ``(V, U, 3)`` f_r of each texel's nearest valid pose under the bi-angular metric, and that distance (rad)."""
        U, V = self.texels
        img = np.zeros((V, U, 3), np.float32)
        dist = np.full((V, U), np.inf)
        for v0 in range(0, V, rows):
            v1 = min(V, v0 + rows)
            p = texel_centres(self.texels, self.size_mm, v0, v1)
            wi, _ = directions_to(p, self.light)  # (rows, U, P, 3)
            wo, _ = directions_to(p, self.camera)
            d = _angle(wi, wi_star) + _angle(wo, wo_star)
            ok = np.asarray(self.valid[v0:v1])
            d = np.where(ok, d, np.inf)
            best = np.argmin(d, axis=-1)
            f = np.asarray(self.f_r[v0:v1])
            img[v0:v1] = np.take_along_axis(f, best[..., None, None], axis=2)[:, :, 0]
            dist[v0:v1] = np.take_along_axis(d, best[..., None], axis=2)[..., 0]
        img[~np.isfinite(dist)] = 0
        return img, dist


MIN_SAMPLES = 3  # fewest samples views (b) and (c) look for before the default tolerance is widened
DEFAULT_TOL_DEG = 15.0
MAX_TOL_DEG = 45.0  # the default tolerance is widened up to this, never further
PREFERRED_THETA_DEG = 30.0  # among equally populated incident directions, the one nearest this elevation


def to_degrees(w: np.ndarray) -> tuple[float, float]:
    """(θ, φ) in degrees of a unit direction (φ in (-180°, 180°])."""
    return float(np.degrees(np.arccos(np.clip(w[2], -1, 1)))), float(np.degrees(np.arctan2(w[1], w[0])))


@dataclass
class ViewChoice:
    """The directions, tolerance and sample selections of the three views for one texel.

    ``wi``/``wo`` are unit vectors with ``wi_deg``/``wo_deg`` their (θ, φ);
    ``*_from`` says where each came from (``"given"`` or how the data chose it);
    ``near`` marks the texel's valid samples within ``tol_deg`` of ω_i (view b),
    ``in_plane`` those of them within ``tol_deg`` of the incidence plane (view c);
    ``notes`` are sentences the titles show (a widened tolerance, nothing near).
    """

    u: int
    v: int
    wi: np.ndarray
    wi_deg: tuple[float, float]
    wi_from: str
    wo: np.ndarray
    wo_deg: tuple[float, float]
    wo_from: str
    tol_deg: float
    phi_plane: float  # azimuth (rad) of the incidence plane
    wis: np.ndarray
    wos: np.ndarray
    lum: np.ndarray
    ok: np.ndarray
    near: np.ndarray
    in_plane: np.ndarray
    notes: list = field(default_factory=list)


def _selections(wis, wos, ok, cands, phis, tol_deg):
    """Masks ``(C, S)``: samples within ``tol`` of each candidate ω_i, and of those the ones within ``tol`` of its plane."""
    tol = np.radians(tol_deg)
    near = ok[None] & (np.arccos(np.clip(cands @ wis.T, -1, 1)) <= tol)
    normals = np.stack([-np.sin(phis), np.cos(phis), np.zeros_like(phis)], -1)  # incidence-plane normals
    off = np.arcsin(np.clip(np.abs(normals @ wos.T), 0, 1))
    return near, near & (off <= tol)


def choose_views(view: Viewer, u: int, v: int, wi: tuple[float, float] | None = None,
                 wo: tuple[float, float] | None = None, tol_deg: float | None = None) -> ViewChoice:
    """Pick the views' directions from the data where the user gave none.

    - ω_i (views b, c and the spatial image): given, or the texel's own incident
      direction whose incidence plane holds the most samples within the tolerance
      (then the most within the tolerance of ω_i; then the elevation nearest 30°).
    - ω_r of the spatial image: given, or that of the texel's pose whose ω_i is
      nearest the chosen one, so the spatial image shows a pose that was measured.
    - tolerance: given (kept, and the titles say when nothing is within it), or
      15° widened in steps up to 45° until the incidence plane holds
      ``MIN_SAMPLES`` samples (the titles say so).
    """
    wis, wos, f, ok = view.texel_samples(u, v)
    ok = ok & np.isfinite(f).all(-1)
    lum = np.where(ok, np.nan_to_num(f) @ LUMA, np.nan)
    notes = []
    auto_tol = tol_deg is None
    steps = [DEFAULT_TOL_DEG] + [t for t in (20.0, 25.0, 30.0, 35.0, 40.0, MAX_TOL_DEG) if t > DEFAULT_TOL_DEG]
    if tol_deg is not None:
        steps = [float(tol_deg)]

    if wi is not None:
        wi_vec, wi_from = direction(*wi), "given"
        cand = wi_vec[None]
        phis = np.array([np.radians(wi[1])])
    else:
        cand = wis[ok]
        if len(cand) > 1000:  # enough candidates to find a populated direction, at bounded cost
            cand = cand[:: int(np.ceil(len(cand) / 1000))]
        if len(cand) == 0:
            cand = direction(PREFERRED_THETA_DEG, 0.0)[None]
            notes.append(f"texel ({u}, {v}) has no valid samples")
        phis = np.arctan2(cand[:, 1], cand[:, 0])
        wi_from = "the most populated incident direction of this texel"

    for tol in steps:
        near, plane = _selections(wis, wos, ok, cand, phis, tol)
        n_plane, n_near = plane.sum(1), near.sum(1)
        theta = np.degrees(np.arccos(np.clip(cand[:, 2], -1, 1)))
        defined = theta >= 3.0  # near the normal the incidence plane is arbitrary
        best = int(np.lexsort((-np.abs(theta - PREFERRED_THETA_DEG), n_near, n_plane, defined))[-1])
        if n_plane[best] >= MIN_SAMPLES or not auto_tol:
            break
    if auto_tol and tol > DEFAULT_TOL_DEG:
        notes.append(f"tolerance widened to {tol:g}° (< {MIN_SAMPLES} samples within {DEFAULT_TOL_DEG:g}°)")
    wi_vec = cand[best]
    phi_plane = float(phis[best])
    near, in_plane = near[best], plane[best]
    if ok.any() and not near.any():
        gap = np.degrees(np.arccos(np.clip(wis[ok] @ wi_vec, -1, 1))).min()
        notes.append(f"no sample within {tol:g}° of ω_i: the nearest is {gap:.0f}° away")
    elif near.any() and not in_plane.any():
        notes.append(f"no sample within {tol:g}° of the incidence plane")
    wi_deg = wi if wi is not None else to_degrees(wi_vec)

    if wo is not None:
        wo_vec, wo_from = direction(*wo), "given"
    elif ok.any():
        d = np.where(ok, np.arccos(np.clip(wis @ wi_vec, -1, 1)), np.inf)
        wo_vec, wo_from = wos[int(np.argmin(d))], "the texel's pose nearest ω_i"
    else:
        wo_vec, wo_from = direction(PREFERRED_THETA_DEG, 180.0), "default"
    wo_deg = wo if wo is not None else to_degrees(wo_vec)
    (wi_theta, wi_phi), (wo_theta, wo_phi) = wi_deg, wo_deg  # pairs, also when given as lists
    return ViewChoice(u, v, wi_vec, (wi_theta, wi_phi), wi_from, wo_vec, (wo_theta, wo_phi), wo_from, float(tol), phi_plane,
                      wis, wos, lum, ok, near, in_plane, notes)


def _fmt(d: tuple[float, float]) -> str:
    return f"({d[0]:.0f}°, {d[1]:.0f}°)" if any(x != round(x) for x in d) else f"({d[0]:g}°, {d[1]:g}°)"


def spatial_figure(view: Viewer, c: ViewChoice):
    """(a): the f_r image at (ω_i, ω_r) beside the bi-angular distance of each texel's nearest pose."""
    import matplotlib.pyplot as plt

    U, V = view.texels
    img, dist = view.spatial(c.wi, c.wo)
    found = np.isfinite(dist)
    scale = float(np.percentile(img[found], 99)) if found.any() else 1.0
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.6))
    shown = np.clip(img / max(scale, 1e-12), 0, 1) ** (1 / 2.2)
    ax[0].imshow(shown, origin="lower", extent=(0, U, 0, V), interpolation="nearest")
    ax[0].plot([c.u + 0.5], [c.v + 0.5], "c+", ms=12)
    deg = np.degrees(np.where(found, dist, np.nan))
    median = float(np.nanmedian(deg)) if found.any() else float("nan")
    at = float(deg[c.v, c.u]) if found[c.v, c.u] else float("nan")
    far = (f"\nNO POSE NEAR these directions: nearest poses are {median:.0f}° away (median)"
           if median > 2 * c.tol_deg else "")
    ax[0].set_title(f"f_r at ω_i={_fmt(c.wi_deg)}, ω_r={_fmt(c.wo_deg)}; white = {scale:.3g} sr⁻¹\n"
                    f"nearest pose per texel: {at:.1f}° at +, median {median:.1f}°{far}", fontsize=9)
    ax[0].set_xlabel("u")
    ax[0].set_ylabel("v")
    im = ax[1].imshow(deg, origin="lower", extent=(0, U, 0, V), cmap="magma")
    ax[1].set_title("bi-angular distance to that pose (deg)", fontsize=9)
    fig.colorbar(im, ax=ax[1])
    fig.tight_layout()
    return fig


def hemisphere_figure(view: Viewer, c: ViewChoice):
    """(b): the texel's samples with ω_i within the tolerance, at their ω_r, coloured by luminance (scaled to them)."""
    import matplotlib.pyplot as plt

    near, lum, wos = c.near, c.lum, c.wos
    fig, ax = plt.subplots(figsize=(5.6, 5.2))
    m = None
    if view.model is not None:
        g = np.linspace(-1, 1, 121)
        X, Y = np.meshgrid(g, g)
        inside = X**2 + Y**2 < 0.999
        wo_grid = np.stack([X[inside], Y[inside], np.sqrt(1 - X[inside] ** 2 - Y[inside] ** 2)], -1)
        m = np.full(X.shape, np.nan)
        m[inside] = view.model_eval(c.u, c.v, c.wi, wo_grid) @ LUMA
    # colour scale from the samples shown; the model's own range only when there are none
    vmin = 0.0
    if near.any():
        lo, vmax = float(np.min(lum[near])), float(np.percentile(lum[near], 98))
        if lo > 0.5 * vmax:  # a narrow range well above 0 (a diffuse texel): spread it over the colour map
            vmin = lo - 0.1 * (vmax - lo)
    elif m is not None and np.isfinite(m).any():
        vmax = float(np.nanpercentile(m, 99))
    elif c.ok.any():
        vmax = float(np.nanpercentile(lum[c.ok], 98))
    else:
        vmax = 1.0
    vmax = vmax if vmax > vmin else vmin + (abs(vmin) or 1.0)
    if m is not None:
        ax.imshow(m, origin="lower", extent=(-1, 1, -1, 1), cmap="viridis", vmin=vmin, vmax=vmax, alpha=0.85)
    sc = ax.scatter(wos[near, 0], wos[near, 1], c=lum[near], cmap="viridis", vmin=vmin, vmax=vmax, edgecolors="k", s=40)
    ax.add_patch(plt.Circle((0, 0), 1, fill=False, color="grey"))
    ax.plot([c.wi[0]], [c.wi[1]], "r*", ms=14, label="ω_i")
    ax.plot([-c.wi[0]], [-c.wi[1]], "wx", ms=10, mew=2, label="mirror")
    ax.set_xlim(-1.05, 1.05)
    ax.set_ylim(-1.05, 1.05)
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8)
    fig.colorbar(sc, ax=ax, label="luminance f_r (sr⁻¹)", extend="both" if vmin > 0 else "max")
    notes = "".join(f"\n{n}" for n in c.notes)
    ax.set_title(f"texel ({c.u}, {c.v}) exitant hemisphere, ω_i={_fmt(c.wi_deg)} ±{c.tol_deg:g}°\n"
                 f"{int(near.sum())} samples" + (f"; model {view.maps.attrs['model']}" if view.maps is not None else "")
                 + notes,
                 fontsize=9)
    fig.tight_layout()
    return fig


def incidence_figure(view: Viewer, c: ViewChoice):
    """(c): the samples near the incidence plane by signed θ_r; the radial axis spans the data shown."""
    import matplotlib.pyplot as plt
    from matplotlib.projections.polar import PolarAxes
    from matplotlib.ticker import MaxNLocator

    phi_i, sel, lum, wos = c.phi_plane, c.in_plane, c.lum, c.wos
    forward = -(wos[:, 0] * np.cos(phi_i) + wos[:, 1] * np.sin(phi_i))  # > 0 on the side away from the light
    theta_signed = np.arccos(np.clip(wos[:, 2], -1, 1)) * np.sign(np.where(forward == 0, 1, forward))
    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="polar")
    assert isinstance(ax, PolarAxes)  # the stubs type add_subplot as plain Axes whatever the projection
    ax.set_theta_zero_location("N")
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    ax.scatter(theta_signed[sel], lum[sel], c="C0", s=25, label="samples")
    data_max = float(np.max(lum[sel])) if sel.any() else 0.0
    curve_max = 0.0
    if view.model is not None:
        th = np.radians(np.linspace(-89, 89, 179))
        wo_line = np.stack([-np.sin(th) * np.cos(phi_i), -np.sin(th) * np.sin(phi_i), np.cos(th)], -1)
        curve = view.model_eval(c.u, c.v, c.wi, wo_line) @ LUMA
        curve_max = float(np.nanmax(curve)) if np.isfinite(curve).any() else 0.0
        clipped = data_max > 0 and curve_max > 2 * data_max
        assert view.maps is not None, "the model comes with its parameter maps"
        label = f"model {view.maps.attrs['model']}" + (f" (peak {curve_max:.3g}, clipped)" if clipped else "")
        ax.plot(th, curve, "C1-", label=label)
    # radial axis from the samples shown (the model's curve only when it is of their size, or there are none)
    if data_max > 0:
        rmax = max(data_max, curve_max if curve_max <= 2 * data_max else 0.0)
    elif curve_max > 0:
        rmax = curve_max
    elif c.ok.any() and np.nanmax(lum[c.ok]) > 0:
        rmax = float(np.nanmax(lum[c.ok]))
    else:
        rmax = 1.0
    rmax *= 1.1
    ax.set_ylim(0, rmax)
    ax.yaxis.set_major_locator(MaxNLocator(4))
    ax.plot([-np.radians(c.wi_deg[0])], [rmax], "r*", ms=12, label="ω_i", clip_on=False)
    notes = "".join(f"\n{n}" for n in c.notes)
    ax.set_title(f"texel ({c.u}, {c.v}) incidence plane, ω_i={_fmt(c.wi_deg)}; {int(sel.sum())} samples "
                 f"within {c.tol_deg:g}°\nθ_r > 0: away from the light; radius: luminance f_r (sr⁻¹){notes}", fontsize=9)
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    return fig


def plot_views(samples_url: str, out_dir: str | Path, params_url: str | None = None, texel: tuple[int, int] | None = None,
               wi: tuple[float, float] | None = None, wo: tuple[float, float] | None = None, tol_deg: float | None = None,
               registry=None) -> list[Path]:
    """Write ``spatial.png``, ``hemisphere.png`` and ``incidence-plane.png`` into ``out_dir``; return their paths.

    ``wi``/``wo`` are (θ, φ) in degrees in the sample frame; ``texel`` is (u, v), default the centre.
    Directions and tolerance left out are chosen from the data (:func:`choose_views`).
    With ``params_url``, ``fit-error.png`` (:func:`error_maps`) is written too.
    """
    from sbrdf_core.extras import require

    # Before any data is read: a plain install (no ``[plot]`` extra) hears the install command, not a traceback.
    matplotlib = require("matplotlib", feature="sbrdf plot")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    view = Viewer(samples_url, params_url, registry)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    U, V = view.texels
    u, v = texel if texel is not None else (U // 2, V // 2)
    choice = choose_views(view, u, v, wi, wo, tol_deg)
    paths = []
    for name, draw in (("spatial.png", spatial_figure), ("hemisphere.png", hemisphere_figure),
                       ("incidence-plane.png", incidence_figure)):
        fig = draw(view, choice)
        paths.append(out / name)
        fig.savefig(paths[-1], dpi=100)
        plt.close(fig)
    if view.model is not None:
        paths.append(error_maps(view.maps, out / "fit-error.png"))
    return paths


def error_maps(maps, path: Path) -> Path:
    """``fit-error.png``: training RMS beside held-out RMS (one colour scale) and the texels each flag marks, and
    with ``coherence: basis`` each texel's basis material.

    Held-out error is what the fit does where it was not trained; a texel much
    brighter on the right than on the left is overfit.
    """
    import matplotlib.pyplot as plt

    rms = maps.read("rms").astype(float)
    names = maps.names()
    held = maps.read("rms_holdout").astype(float) if "rms_holdout" in names else np.full(rms.shape, np.nan)
    flags = maps.read("flags").astype(int)
    bits = {int(b): text for b, text in maps.attrs.get("flag_bits", {}).items()}
    finite = np.concatenate([rms[np.isfinite(rms)], held[np.isfinite(held)]])
    vmax = float(np.percentile(finite, 99)) if finite.size else 1.0
    material = maps.read("material") if "material" in names else None
    if material is None:
        fig, ax = plt.subplots(1, 3, figsize=(14, 4.4))
    else:  # room right of the flags for their legend
        fig, ax = plt.subplots(1, 4, figsize=(20, 4.4), gridspec_kw={"wspace": 0.7})
    for a, data, title in ((ax[0], rms, "training RMS"), (ax[1], held, "held-out RMS (NaN: none held out)")):
        im = a.imshow(data, origin="lower", cmap="magma", vmin=0, vmax=vmax, interpolation="nearest")
        shown = data[np.isfinite(data)]
        a.set_title(f"{title}\nmean {shown.mean():.3g} sr⁻¹" if shown.size else title, fontsize=9)
        a.set_xlabel("u")
        a.set_ylabel("v")
    fig.colorbar(im, ax=ax[:2], label="sr⁻¹")
    labels = ["fine"] + [f"{b}: {bits.get(b, '')[:38]}" for b in sorted(bits) if (flags & b).any()]
    code = np.zeros(flags.shape)
    for i, b in enumerate(b for b in sorted(bits) if (flags & b).any()):
        code = np.where(flags & b, i + 1, code)  # the highest set bit shown
    im = ax[2].imshow(code, origin="lower", cmap="tab10", vmin=-0.5, vmax=9.5, interpolation="nearest")
    ax[2].set_title("flags (highest bit per texel)", fontsize=9)
    handles = [plt.Rectangle((0, 0), 1, 1, color=plt.cm.tab10(i)) for i in range(len(labels))]
    ax[2].legend(handles, labels, fontsize=6, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    if material is not None:  # 255: no training samples, nothing clustered
        shown = np.ma.masked_equal(np.asarray(material, int), 255)
        ax[3].imshow(shown, origin="lower", cmap="tab20", vmin=-0.5, vmax=19.5, interpolation="nearest")
        ax[3].set_title(f"basis material (labels per tile; up to {int(shown.max()) + 1 if shown.count() else 0})",
                        fontsize=9)
        ax[3].set_xlabel("u")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
