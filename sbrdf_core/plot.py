"""``sbrdf plot``: McAllister's SBRDF viewer (seed 000 §3.7) as three matplotlib figures.

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

The spatial image reads the texel grid a band of rows at a time (every pose of
those rows), so plotting a multi-GB scan does not load it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import SbrdfError
from .geometry import directions_to, texel_centres

LUMA = np.array([0.2126, 0.7152, 0.0722])  # linear sRGB / Rec. 709 luminance weights


def direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0))


class Viewer:
    """Reads one SampledReflectance (and optionally a ParamMaps) and draws the three views."""

    def __init__(self, samples_url: str, params_url: str | None = None, registry=None):
        from .store import open_artifact

        self.art = open_artifact(samples_url, kind="SampledReflectance")
        self.texels = tuple(int(x) for x in self.art.attrs["texels"])  # (U, V)
        self.size_mm = tuple(float(x) for x in self.art.attrs["size_mm"])
        self.light = self.art.read("light_pos")
        self.camera = self.art.read("camera_pos")
        self.f_r = self.art.zarr_array("f_r")
        self.valid = self.art.zarr_array("valid")
        self.model = self.maps = None
        if params_url:
            pm = open_artifact(params_url, kind="ParamMaps")
            from .registry import default_registry

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
        params = {p.name: np.asarray(self.maps.zarr_array(f"params/{p.name}")[v, u], float).reshape(1, -1)
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


def plot_views(samples_url: str, out_dir: str | Path, params_url: str | None = None, texel: tuple[int, int] | None = None,
               wi: tuple[float, float] = (30.0, 0.0), wo: tuple[float, float] = (30.0, 180.0), tol_deg: float = 15.0,
               registry=None) -> list[Path]:
    """Write ``spatial.png``, ``hemisphere.png`` and ``incidence-plane.png`` into ``out_dir``; return their paths.

    ``wi``/``wo`` are (θ, φ) in degrees in the sample frame; ``texel`` is (u, v), default the centre.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    view = Viewer(samples_url, params_url, registry)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    U, V = view.texels
    u, v = texel if texel is not None else (U // 2, V // 2)
    wi_s, wo_s = direction(*wi), direction(*wo)
    paths = []

    # (a) spatial image
    img, dist = view.spatial(wi_s, wo_s)
    scale = np.percentile(img[np.isfinite(dist)], 99) if np.isfinite(dist).any() else 1.0
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.4))
    shown = np.clip(img / max(scale, 1e-12), 0, 1) ** (1 / 2.2)
    ax[0].imshow(shown, origin="lower", extent=(0, U, 0, V), interpolation="nearest")
    ax[0].plot([u + 0.5], [v + 0.5], "c+", ms=12)
    ax[0].set_title(f"f_r at ω_i=({wi[0]:g}°, {wi[1]:g}°), ω_r=({wo[0]:g}°, {wo[1]:g}°)\nnearest pose per texel; "
                    f"white = {scale:.3g} sr⁻¹", fontsize=9)
    ax[0].set_xlabel("u")
    ax[0].set_ylabel("v")
    im = ax[1].imshow(np.degrees(np.where(np.isfinite(dist), dist, np.nan)), origin="lower", extent=(0, U, 0, V), cmap="magma")
    ax[1].set_title("bi-angular distance to that pose (deg)", fontsize=9)
    fig.colorbar(im, ax=ax[1])
    fig.tight_layout()
    paths.append(out / "spatial.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    # (b) exitant hemisphere of one texel
    wis, wos, f, ok = view.texel_samples(u, v)
    lum = f @ LUMA
    near = ok & (np.degrees(_angle(wis, wi_s)) <= tol_deg)
    fig, ax = plt.subplots(figsize=(5.6, 5))
    vmax = float(np.percentile(lum[near], 98)) if near.any() else 1.0
    if view.model is not None:
        g = np.linspace(-1, 1, 121)
        X, Y = np.meshgrid(g, g)
        inside = X**2 + Y**2 < 0.999
        wo_grid = np.stack([X[inside], Y[inside], np.sqrt(1 - X[inside] ** 2 - Y[inside] ** 2)], -1)
        m = np.full(X.shape, np.nan)
        m[inside] = view.model_eval(u, v, wi_s, wo_grid) @ LUMA
        vmax = max(vmax, float(np.nanpercentile(m, 99)))
        ax.imshow(m, origin="lower", extent=(-1, 1, -1, 1), cmap="viridis", vmin=0, vmax=vmax, alpha=0.85)
    sc = ax.scatter(wos[near, 0], wos[near, 1], c=lum[near], cmap="viridis", vmin=0, vmax=vmax, edgecolors="k", s=40)
    ax.add_patch(plt.Circle((0, 0), 1, fill=False, color="grey"))
    ax.plot([wi_s[0]], [wi_s[1]], "r*", ms=14, label="ω_i")
    ax.plot([-wi_s[0]], [-wi_s[1]], "wx", ms=10, mew=2, label="mirror")
    ax.set_xlim(-1.05, 1.05)
    ax.set_ylim(-1.05, 1.05)
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8)
    fig.colorbar(sc, ax=ax, label="luminance f_r (sr⁻¹)")
    ax.set_title(f"texel ({u}, {v}) exitant hemisphere, ω_i=({wi[0]:g}°, {wi[1]:g}°) ±{tol_deg:g}°\n"
                 f"{int(near.sum())} samples" + (f"; model {view.maps.attrs['model']}" if view.model else ""), fontsize=9)
    fig.tight_layout()
    paths.append(out / "hemisphere.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    # (c) incidence-plane polar plot
    phi_i = np.arctan2(wi_s[1], wi_s[0])
    n_plane = np.array([-np.sin(phi_i), np.cos(phi_i), 0.0])  # normal of the incidence plane
    off = np.degrees(np.arcsin(np.clip(np.abs(wos @ n_plane), 0, 1)))
    sel = near & (off <= tol_deg)
    forward = -(wos[:, 0] * np.cos(phi_i) + wos[:, 1] * np.sin(phi_i))  # > 0 on the side away from the light
    theta_signed = np.arccos(np.clip(wos[:, 2], -1, 1)) * np.sign(np.where(forward == 0, 1, forward))
    fig = plt.figure(figsize=(6, 4.8))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    ax.scatter(theta_signed[sel], lum[sel], c="C0", s=25, label="samples")
    if view.model is not None:
        th = np.radians(np.linspace(-89, 89, 179))
        wo_line = np.stack([-np.sin(th) * np.cos(phi_i), -np.sin(th) * np.sin(phi_i), np.cos(th)], -1)
        ax.plot(th, view.model_eval(u, v, wi_s, wo_line) @ LUMA, "C1-", label=f"model {view.maps.attrs['model']}")
    ax.plot([-np.radians(wi[0])], [ax.get_ylim()[1] if sel.any() else 1], "r*", ms=12, label="ω_i")
    ax.set_title(f"texel ({u}, {v}) incidence plane, ω_i=({wi[0]:g}°, {wi[1]:g}°); {int(sel.sum())} samples "
                 f"within {tol_deg:g}°\nθ_r > 0: away from the light; radius: luminance f_r (sr⁻¹)", fontsize=9)
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    paths.append(out / "incidence-plane.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    if view.model is not None:
        paths.append(error_maps(view.maps, out / "fit-error.png"))
    return paths


def error_maps(maps, path: Path) -> Path:
    """``fit-error.png``: training RMS beside held-out RMS (one colour scale) and the texels each flag marks.

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
    fig, ax = plt.subplots(1, 3, figsize=(14, 4.4))
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
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
