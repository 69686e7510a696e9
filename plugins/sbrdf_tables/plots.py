"""Figures of seed 004 §2.3/§3.4.2: polar plot matrix and in-plane 1-D plots, measurement vs model.

Both use the cube root of the transfer probability, as the thesis does, so
the diffuse floor and the peak are visible in one figure.  Matplotlib with
the Agg backend: PNG files, no display needed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def model_p(model, params, table) -> np.ndarray:
    """The model's transfer probability at every entry of ``table`` (first channel)."""
    return model.eval(params, table.wi[None], table.wo[None])[0, :, 0] * table.abs_cos_o


def polar_matrix(table, path, model=None, params=None, title="") -> Path:
    """One polar subplot per incident direction (rows θ_i, columns ϕ_i): θ_o as radius, ϕ_o as angle.

    With a model, each incident direction gets the measurement (left) and the
    model (right) side by side on the same cube-root colour scale.  The
    transmission hemisphere, when present, is a second row per θ_i.
    """
    plt = _pyplot()
    thetas = np.unique(table.theta_i)
    phis = np.unique(table.phi_i)
    has_t = table.transmission.any()
    sources = [("measured", np.where(table.measured, table.p, np.nan))]
    if model is not None:
        sources.append(("model", model_p(model, params, table)))
    rows = len(thetas) * (2 if has_t else 1)
    cols = len(phis) * len(sources)
    fig, axes = plt.subplots(rows, cols, subplot_kw={"projection": "polar"}, figsize=(1.6 * cols, 1.6 * rows),
                             squeeze=False)
    vmax = np.nanmax(np.cbrt(sources[0][1])) if np.isfinite(sources[0][1]).any() else 1.0
    for r, ti in enumerate(thetas):
        for c, pi_ in enumerate(phis):
            sel = (table.theta_i == ti) & (table.phi_i == pi_)
            for s, (label, values) in enumerate(sources):
                for h, lower in enumerate((False, True) if has_t else (False,)):
                    ax = axes[r * (2 if has_t else 1) + h, c * len(sources) + s]
                    ax.set_xticks([]), ax.set_yticks([])
                    part = sel & (table.transmission == lower)
                    if not part.any():
                        ax.set_axis_off()
                        continue
                    radius = np.where(lower, 180.0 - table.theta_o, table.theta_o)[part]
                    # the light at the top of each subplot (thesis convention): rotate so ϕ_i points up
                    angle = np.radians(table.phi_o[part] - pi_ + 90.0)
                    # the background is the colour map's zero, so gaps between sparse samples near the rim read as 0
                    ax.set_facecolor(plt.get_cmap("inferno")(0.0))
                    ax.scatter(angle, radius, c=np.cbrt(values[part]), s=6, linewidths=0, cmap="inferno", vmin=0,
                               vmax=vmax)
                    ax.set_ylim(0, 90)
                    if r == 0 and h == 0:
                        ax.set_title(f"{label}\nϕi={pi_:g}°", fontsize=6)
                    if c == 0 and s == 0:
                        ax.set_ylabel(f"θi={ti:g}°{' T' if lower else ''}", fontsize=6)
    if title:
        fig.suptitle(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def in_plane(table, path, model=None, params=None, phi_i=None, title="") -> Path:
    """p^(1/3) against signed θ_o in the plane of incidence, one panel per θ_i: measurement green, model red.

    The plane holds the entries with ϕ_o = ϕ_i (plotted at −θ_o, the light's side) and ϕ_o = ϕ_i + 180°
    (+θ_o, the mirror side); transmission entries continue past ±90°.
    """
    plt = _pyplot()
    phi_i = float(np.unique(table.phi_i)[0]) if phi_i is None else float(phi_i)
    thetas = np.unique(table.theta_i[table.phi_i == phi_i])
    fig, axes = plt.subplots(1, len(thetas), figsize=(2.4 * len(thetas), 2.4), squeeze=False)
    pred = model_p(model, params, table) if model is not None else None
    for k, ti in enumerate(thetas):
        ax = axes[0, k]
        sel = (table.theta_i == ti) & (table.phi_i == phi_i)
        dphi = (table.phi_o - phi_i) % 360.0
        same, opposite = sel & np.isclose(dphi, 0.0), sel & np.isclose(dphi, 180.0)
        x = np.concatenate([-table.theta_o[same], table.theta_o[opposite]])
        idx = np.concatenate([np.flatnonzero(same), np.flatnonzero(opposite)])
        order = np.argsort(x)
        ax.plot(x[order], np.cbrt(table.p[idx][order]), "g.-", ms=2, lw=0.8, label="measured")
        if pred is not None:
            ax.plot(x[order], np.cbrt(pred[idx][order]), "r-", lw=0.8, label="model")
        ax.set_title(f"θi={ti:g}°, ϕi={phi_i:g}°", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_xlabel("θo (signed, °)", fontsize=6)
    axes[0, 0].set_ylabel("p^(1/3)", fontsize=7)
    axes[0, 0].legend(fontsize=6)
    if title:
        fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
