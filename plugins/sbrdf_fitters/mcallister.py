"""mcallister: McAllister's SBRDF fitting procedure (seed 000 §4.3, notes §8).

1. ρ_d per colour channel from the texel's samples: a low percentile (10th by
   default; the minimum is biased low by noise and registration error),
   ``min`` (Eq 4.5), or Marschner's (N·ω_i)(N·ω_r)-weighted mean.
2. Specular residual f_s = f_r − ρ_d and its luminance f̄_s (weights of the
   chosen colour space, Eq 2.3).
3. Lobe shape fitted to f̄_s: batched Levenberg–Marquardt (1..N lobes, the
   text's initial guesses, lobe 2 optionally started from the 1-lobe fit), or
   the single-lobe line search (Eq 4.8–4.9, ``line-search`` fitter).
4. ρ_s colour by Eq 4.10, ρ_s,* = mean_k f_s,k / f̄_s,k, over samples whose
   luminance residual is at least ``rho_s_guard`` of the texel's largest (the
   ratio explodes where f̄_s ≈ 0; the text gives no guard).  ρ_s,* has unit
   luminance; each lobe's ρ_s,j = a_j·ρ_s,* with a_j the lobe's fitted
   luminance magnitude (the C_z = 1 gauge).
"""

from __future__ import annotations

import logging

import numpy as np

from sbrdf_core.brdf import above_horizon, luminance_weights
from sbrdf_core.errors import ParameterError
from sbrdf_core.nodes.fit import NONFINITE_INPUT, NONFINITE_RESULT, NOT_CONVERGED, FitResult, rms_error
from sbrdf_core.nodes.fit import usable as usable_samples
from sbrdf_core.params import Param
from sbrdf_core.types import PluginRegistry
from sbrdf_lib.lm import diffuse_percentile, fit_model

from .declarations import LINE_SEARCH, MCALLISTER
from .line_search import line_search_lobe

logger = logging.getLogger(__name__)


def diffuse_estimate(f_r, valid, wi, wo, method: str, percentile: float) -> np.ndarray:
    """ρ_d ``(T, 3)`` by ``percentile``, ``min`` or ``weighted-mean`` over valid samples."""
    if method == "percentile":
        return diffuse_percentile(f_r, valid, percentile)
    if method == "min":
        return diffuse_percentile(f_r, valid, 0.0)
    w = valid * np.clip(wi[..., 2], 0, None) * np.clip(wo[..., 2], 0, None)
    return np.clip((f_r * w[..., None]).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-300)[:, None], 0.0, None)


class McAllisterFitter:
    """McAllister's procedure: percentile ρ_d, lobes fitted to the luminance residual, ρ_s colour by Eq 4.10.

    The luminance lobes are a one-channel Lafortune model, created through the
    registry (:meth:`bind`), so this fitter imports no model plugin.
    """

    model_name = "lafortune"
    model_config: dict

    params: tuple[Param, ...] = MCALLISTER  # the line-search fitter declares its own

    def __init__(self, *, model: str = "lafortune", model_params: dict = {}, diffuse: str = "percentile",  # noqa: B006
                 percentile: float = 10.0, colour_space: str = "mcallister", rho_s_guard: float = 0.05,
                 lobe_fit: str = "lm", lobe_2_start: str = "text", iterations: int = 200, tolerance: float = 1e-4,
                 starts: int = 1, objective: str = "root", root_floor: float = 0.01):
        # model_params' default equals the declaration (the registry checks) and is only read, never changed.
        self.model_config = dict(model_params)
        self._registry: PluginRegistry | None = None
        self.diffuse, self.percentile, self.colour_space = diffuse, percentile, colour_space
        self.lobe_fit, self.lobe_2_start, self.rho_s_guard = lobe_fit, lobe_2_start, rho_s_guard
        self.iterations, self.tolerance, self.starts, self.objective = iterations, tolerance, starts, objective
        self.root_floor = root_floor
        self.weights = luminance_weights(colour_space)
        for _, msg in self.check_params({"lobe_fit": lobe_fit, "model_params": self.model_config}):
            raise ParameterError(msg)

    @staticmethod
    def check_params(params) -> list[tuple[str, str]]:
        """The line search fits exactly one lobe and no β: say so at graph load, with the line."""
        cfg = params.get("model_params") or {}
        if params.get("lobe_fit", "line-search") == "line-search" and (int(cfg.get("lobes", 1)) != 1 or cfg.get("beta")):
            return [("model_params", "the line search fits exactly one lobe without beta (seed 000 §4.3.2); "
                                     f"got model_params {dict(cfg)}")]
        return []

    def bind(self, registry: PluginRegistry) -> None:
        """The registry the one-channel lobe models come from (the runner calls this after construction)."""
        self._registry = registry

    def __getstate__(self):
        # A registry holds locks and hook managers; a fitter shipped to a worker re-binds to the default one.
        return {**self.__dict__, "_registry": None}

    def _lafortune(self, lobes: int, anisotropic: bool, beta: bool):
        """A one-channel Lafortune model (McAllister's lobe fit runs on luminance)."""
        if self._registry is None:
            from sbrdf_core.registry import default_registry

            self._registry = default_registry()
        model = self._registry.create("brdf-model", "lafortune", {"lobes": lobes, "anisotropic": anisotropic, "beta": beta})
        return model.single_channel()

    def fit(self, model, f_r, valid, wi, wo, *, limits=None, rms=True, usable=False,
            initial=None) -> FitResult:  # initial: no refinement from a given start here
        T = f_r.shape[0]
        f_r, valid = usable_samples(f_r, valid)
        # A sample whose direction is not finite cannot be used: left in, its NaN reaches every product the line
        # search and Eq 4.10 sum over (0 · NaN is NaN), and the whole texel comes out non-finite.
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        aimed = np.isfinite(wi).all(axis=-1) & np.isfinite(wo).all(axis=-1)
        dropped = (valid & ~aimed).any(axis=1)
        if not aimed.all():
            valid = valid & aimed
            f_r = np.where(valid[..., None], f_r, 0.0)
            up = np.array([0.0, 0.0, 1.0])
            wi, wo = np.where(aimed[..., None], wi, up), np.where(aimed[..., None], wo, up)
        use = valid & above_horizon(wi, wo)
        rho_d = diffuse_estimate(f_r, use, wi, wo, self.diffuse, self.percentile)
        f_s = np.where(use[..., None], f_r - rho_d[:, None, :], 0.0)
        lum = f_s @ self.weights  # (T, S)
        converged = np.ones(T, bool)
        if model.lobes == 0:
            lobes = []
        elif self.lobe_fit == "line-search":
            pxx, pyy, pzz, _ = model.lobe_dots({}, wi, wo)
            peak = np.max(np.where(use, lum, 0.0), axis=1, keepdims=True)
            keep = use & (lum > np.maximum(self.root_floor * peak, 0.0))
            c, n, _ = line_search_lobe(lum, keep, pxx, pyy, pzz, anisotropic=model.anisotropic,
                                       objective=self.objective)
            lobes = [{"a": np.ones(T), "c": c, "exponent": n}]
        else:
            lobes, converged = self._lm_lobes(model, lum, use, wi, wo)
        rho_star = self._specular_colour(f_s, lum, use)
        params = {"rho_d": rho_d}
        for j, lobe in enumerate(lobes, 1):
            params[f"rho_s_{j}"] = lobe["a"][:, None] * rho_star
            if model.anisotropic:
                params[f"c_x_{j}"], params[f"c_y_{j}"] = lobe["c"][:, :1], lobe["c"][:, 1:2]
            else:
                params[f"c_xy_{j}"] = lobe["c"][:, :1]
            params[f"c_z_{j}"] = lobe["c"][:, 2:3]
            params[f"exponent_{j}"] = np.clip(lobe["exponent"], 0.1, 20000.0)[:, None]
        if model.has_beta:
            params["beta"] = lobes[0]["beta"][:, None] if lobes and "beta" in lobes[0] else np.zeros((T, 1))
        if model.mirror:
            params["rho_m"] = np.zeros((T, 3))
        lo, hi = model.bounds()  # a degenerate line-search lobe (C ≈ 0) must still land inside the declaration
        x = np.clip(model.pack({**model.defaults(T), **params}), lo, hi)
        broken = ~np.isfinite(x).all(axis=1)  # whatever still went wrong: the defaults, flagged, never NaN
        x[broken] = model.pack(model.defaults(int(broken.sum())))
        params = model.unpack(x)
        flags = (np.where(converged, 0, NOT_CONVERGED) | np.where(dropped, NONFINITE_INPUT, 0)
                 | np.where(broken, NONFINITE_RESULT, 0)).astype(np.uint8)
        return FitResult(params, rms_error(model, params, f_r, valid, wi, wo), valid.sum(axis=1), flags)

    def _lm_lobes(self, model, lum, use, wi, wo):
        """Eq 4.7: lobes without colour fitted to the luminance residual, in the C_z = 1 gauge."""
        scalar = self._lafortune(model.lobes, model.anisotropic, model.has_beta)
        form = scalar.fit_form()
        data = lum[..., None]
        opts = dict(iterations=self.iterations, tolerance=self.tolerance, fixed=("rho_d",), starts=self.starts)
        start = _zero_diffuse(form, data, use, wi, wo)
        if model.lobes >= 2 and self.lobe_2_start == "one-lobe":
            one = self._lafortune(1, model.anisotropic, model.has_beta)
            first, _, _ = fit_model(one, data, use, wi, wo, initial=_zero_diffuse(one.fit_form(), data, use, wi, wo), **opts)
            one_form = one.fit_form().from_model(first)
            for k, v in one_form.items():
                if k.endswith("_1") or k == "beta":
                    start[k] = v
            start = form.refine_linear(start, data, use, wi, wo)
        fitted, converged, _ = fit_model(scalar, data, use, wi, wo, initial=start, **opts)
        fitted = scalar.canonical(fitted)
        lobes = []
        for lobe in scalar.lobe_list(fitted):
            entry = {"a": lobe["rho_s"][:, 0], "c": np.concatenate([lobe["c_x"], lobe["c_y"], lobe["c_z"]], axis=1),
                     "exponent": lobe["exponent"][:, 0]}
            if scalar.has_beta:
                entry["beta"] = fitted["beta"][:, 0]
            lobes.append(entry)
        return lobes, converged

    def _specular_colour(self, f_s, lum, use):
        """Eq 4.10 over samples with a luminance residual ≥ guard × the texel's largest; grey where none."""
        peak = np.max(np.where(use, lum, 0.0), axis=1, keepdims=True)
        ok = use & (lum > np.maximum(self.rho_s_guard * peak, 1e-12))
        ratio = np.where(ok[..., None], f_s / np.where(ok, lum, 1.0)[..., None], 0.0)
        count = ok.sum(axis=1)[:, None]
        grey = np.ones(3) / self.weights.sum()
        return np.where(count > 0, ratio.sum(axis=1) / np.maximum(count, 1), grey)


class LineSearchFitter(McAllisterFitter):
    """McAllister's fast single-lobe fit: his procedure with the lobe shape from the line search (§4.3.2)."""

    params = LINE_SEARCH

    def __init__(self, *, model: str = "lafortune", model_params: dict = {}, diffuse: str = "percentile",  # noqa: B006
                 percentile: float = 10.0, colour_space: str = "mcallister", rho_s_guard: float = 0.05,
                 objective: str = "root", root_floor: float = 0.01):
        super().__init__(model=model, model_params=model_params, diffuse=diffuse, percentile=percentile,
                         colour_space=colour_space, rho_s_guard=rho_s_guard, lobe_fit="line-search",
                         lobe_2_start="text", iterations=1, tolerance=0.0, starts=1, objective=objective,
                         root_floor=root_floor)

    @staticmethod
    def check_params(params) -> list[tuple[str, str]]:
        return McAllisterFitter.check_params({**params, "lobe_fit": "line-search"})


def _zero_diffuse(form, data, use, wi, wo):
    start = form.initial_guess(data, use, wi, wo)
    start["rho_d"] = np.zeros_like(start["rho_d"])
    return form.refine_linear(start, data, use, wi, wo)
