"""lafortune_fit: the Lafortune fit form (C_z = 1, log n) and its kernel, what fitters iterate on.

:func:`fit_kernel` is the model's mathematics for the fitting engine (f_r and its Jacobian at one direction pair):
the compiled CPU loop and the GLSL of ``lm-gl`` are both made from it.  ``eval`` and ``jacobian`` of
:class:`~sbrdf_models.lafortune.LafortuneModel` are its NumPy reference.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from sbrdf_core.brdf import LOG_CAP, BRDFModel, above_horizon, positive_power

from .lafortune import (
    DEAD_LOBE,
    FIT_C_BOUNDS,
    MAX_LOG_EXPONENT_STEP,
    OUTLIER_RATIO,
    START_EXPONENTS,
    TRAPPED,
    LafortuneModel,
)
from .lafortune_bounds import EXPONENT_BOUNDS, _apply_lobe_bounds, neutralise


def fit_kernel(x, cfg, wi, wo, f, J):
    """f_r and ∂f_r/∂x of the fit form (C_z = 1, log n) at one direction pair: the fitting engine's kernel.

    ``cfg`` = (lobes, anisotropic, beta); ``x`` in :meth:`LafortuneFitForm.pack` order: ρ_d, then per lobe
    ρ_s, C_xy (or C_x, C_y), log n, then β.  The numbers of ``eval`` and ``jacobian`` (their test oracle),
    caps of :func:`~sbrdf_core.brdf.positive_power` included.
    """
    nc, K = f.size, x.size
    lobes, aniso, has_beta = int(cfg[0]), cfg[1] != 0.0, cfg[2] != 0.0
    for c in range(nc):
        f[c] = 0.0
        for k in range(K):
            J[c, k] = 0.0
    if wi[2] <= 0.0 or wo[2] <= 0.0:
        return
    ix, iy, ox, oy = wi[0], wi[1], wo[0], wo[1]
    if has_beta:
        cb, sb = math.cos(x[K - 1]), math.sin(x[K - 1])
        ix, iy = cb * wi[0] + sb * wi[1], -sb * wi[0] + cb * wi[1]
        ox, oy = cb * wo[0] + sb * wo[1], -sb * wo[0] + cb * wo[1]
    pxx, pyy, pzz = ix * ox, iy * oy, wi[2] * wo[2]
    for c in range(nc):
        f[c] = x[c]
        J[c, c] = 1.0
    k = nc
    for _ in range(lobes):
        rs = k
        kc = k + nc
        cx = x[kc]
        cy = x[kc + 1] if aniso else cx
        kn = kc + (2 if aniso else 1)
        k = kn + 1
        n = math.exp(x[kn])
        d = cx * pxx + cy * pyy + pzz
        s = dsdx = dsdn = 0.0
        if d > 0.0:
            logd = math.log(d)
            s = math.exp(min(max(n * logd, -745.0), LOG_CAP))
            dsdx = n * math.exp(min(max((n - 1.0) * logd, -745.0), LOG_CAP))
            dsdn = s * logd * n
        for c in range(nc):
            rho = x[rs + c]
            f[c] += rho * s
            J[c, rs + c] = s
            if aniso:
                J[c, kc] = rho * dsdx * pxx
                J[c, kc + 1] = rho * dsdx * pyy
            else:
                J[c, kc] = rho * dsdx * (pxx + pyy)
            J[c, kn] = rho * dsdn
            if has_beta:
                J[c, K - 1] += rho * dsdx * (cx - cy) * (iy * ox + ix * oy)


class LafortuneFitForm(LafortuneModel):
    """The same lobes with C_z = 1 fixed and log n: what fitters iterate on."""

    name = "lafortune-fit-form"

    def __init__(self, model: LafortuneModel):
        self.lobes, self.anisotropic, self.has_beta, self.mirror = model.lobes, model.anisotropic, model.has_beta, model.mirror
        self.channels = model.channels
        self.model = model
        self.parameters = self._declare(fit_form=True)
        self.fit_outlier_ratio = OUTLIER_RATIO if self.lobes >= 2 else None

    fit_kernel = staticmethod(fit_kernel)

    def kernel_config(self) -> np.ndarray:
        return np.array([self.lobes, self.anisotropic, self.has_beta], np.float64)

    def lobe_list(self, params):
        out = []
        for j in range(1, self.lobes + 1):
            cx = params[f"c_x_{j}"] if self.anisotropic else params[f"c_xy_{j}"]
            cy = params[f"c_y_{j}"] if self.anisotropic else cx
            out.append({"rho_s": params[f"rho_s_{j}"], "c_x": cx, "c_y": cy, "c_z": np.ones_like(cx),
                        "exponent": np.exp(np.asarray(params[f"log_exponent_{j}"]))})
        return out

    def jacobian(self, params, wi, wo):
        return self._jacobian(params, wi, wo, fit_form=True)

    def fit_trapped(self, x):
        """Rows of a multi-lobe fit where LM lost the forward lobe (:data:`TRAPPED`): a lobe is dead and every live
        lobe scatters backwards (the specular carried by none), or a lobe is a faint spike at the exponent bound,
        fitting a sample or two.  A lobe without magnitude gets no gradient in its shape, so LM cannot bring it back.  A
        dead lobe beside a forward one is not flagged: that is how a 2-lobe fit of one-lobe data ends (GGX data:
        every texel).  McAllister's data (benchmarks/fit.py): 9 of the 11 texels lm2 fitted worse than the peer."""
        if self.lobes < 2:  # one lobe: flagging a backward one cost 25 % of lm's time for 4 texels in 4096
            return np.zeros(x.shape[0], bool)
        p = self.unpack(x)
        dead, faint, spike = TRAPPED
        lobes = range(1, self.lobes + 1)
        peak = np.stack([p[f"rho_s_{j}"].max(axis=1) for j in lobes], axis=1)
        log_n = np.concatenate([p[f"log_exponent_{j}"] for j in lobes], axis=1)
        names = ("c_x", "c_y") if self.anisotropic else ("c_xy",)
        backward = np.stack([np.mean([p[f"{nm}_{j}"][:, 0] for nm in names], axis=0) > 0 for j in lobes], axis=1)
        strongest = peak.max(axis=1, keepdims=True)
        gone = peak <= dead * strongest
        spiked = (peak <= faint * strongest) & (log_n >= np.log(spike * EXPONENT_BOUNDS[1]))
        return (spiked.any(axis=1) | (gone.any(axis=1) & (backward | gone).all(axis=1))) & (strongest[:, 0] > 0)

    def fit_form(self):
        return self

    def limit_box(self, limits, lo, hi):
        """The box part of ``limits`` for the fitting engine: no lobe sharper than the sampling resolves
        (log n ≤ log ``limits.max_cosine_exponent()``); the peak is projected afterwards (:meth:`constrain`)."""
        if limits.resolution is None:
            return lo, hi
        cap = np.log(np.clip(np.asarray(limits.max_cosine_exponent(), np.float64), *EXPONENT_BOUNDS))
        where = self.slices()
        for j in range(1, self.lobes + 1):
            k = where[f"log_exponent_{j}"]
            hi[:, k] = np.minimum(hi[:, k], cap)
        return np.minimum(lo, hi), hi

    def nested(self):
        """Lafortune with one lobe fewer, and its packed fit-form rows embedded here with the last lobe dead
        (ρ_s = 0 at its default shape): what ``lm`` compares a fit with, so a lobe more never fits worse."""
        if self.lobes < 2:
            return None
        smaller = copy.copy(self.model)
        smaller.lobes = self.lobes - 1
        smaller.parameters = smaller._declare(fit_form=False)
        sform = smaller.fit_form()

        def embed(x_small):
            params = sform.unpack(x_small)
            out = self.defaults(x_small.shape[0])
            out.update(params)
            j = self.lobes
            out[f"rho_s_{j}"] = np.zeros_like(out[f"rho_s_{j}"])
            return self.pack(out)

        return smaller, embed

    @property
    def max_step(self) -> np.ndarray:
        """Longest LM step per packed parameter: :data:`MAX_LOG_EXPONENT_STEP` in each log n, the rest unbounded."""
        out = np.full(self.size, np.inf)
        for name, where in self.slices().items():
            if name.startswith("log_exponent_"):
                out[where] = MAX_LOG_EXPONENT_STEP
        return out

    def to_model(self, params):
        """Back to the model's form; a *dead* lobe (ρ_s below DEAD_LOBE) is reset to a harmless shape.

        A fit may park an unneeded lobe at ρ_s ≈ 1e-29 with |C| = 10 and
        n = 20000: invisible at the sampled directions, but at grazing angles
        |C·ω|^n explodes, and any quantization of ρ_s turns it into 1e18 sr⁻¹.
        """
        out = {k: np.asarray(v) for k, v in params.items() if not k.startswith("log_exponent_")}
        for j in range(1, self.lobes + 1):
            out[f"c_z_{j}"] = np.ones_like(np.asarray(params[f"log_exponent_{j}"]))
            out[f"exponent_{j}"] = np.exp(np.asarray(params[f"log_exponent_{j}"]))
            neutralise(self, out, j, np.asarray(params[f"rho_s_{j}"]).max(axis=1, keepdims=True) < DEAD_LOBE)
        if self.has_beta:
            out["beta"] = np.mod(np.asarray(params["beta"]) + np.pi / 2, np.pi) - np.pi / 2
        if self.mirror:
            out["rho_m"] = np.zeros_like(np.asarray(params["rho_d"]))
        return out

    def from_model(self, params):
        canon = self.model.canonical(params)
        out = {k: v for k, v in canon.items() if not (k.startswith("c_z_") or k.startswith("exponent_") or k == "rho_m")}
        for j in range(1, self.lobes + 1):
            out[f"log_exponent_{j}"] = np.log(np.clip(canon[f"exponent_{j}"], *EXPONENT_BOUNDS))
            for nm in (("c_x", "c_y") if self.anisotropic else ("c_xy",)):
                out[f"{nm}_{j}"] = np.clip(out[f"{nm}_{j}"], *FIT_C_BOUNDS)
        return out

    def initial_guess(self, f_r, valid, wi, wo):
        """ρ_d the 10th percentile of the samples (seed 000 §4.3); lobe 1's exponent the best of
        :data:`START_EXPONENTS` for the texel (the text's n = 10 among them), each scored with the lobes'
        magnitudes solved: every texel starts near its own sharpness, which saves LM iterations."""
        from sbrdf_core.engine import solve_linear

        T = f_r.shape[0]
        params = self.defaults(T)
        from sbrdf_lib.lm import diffuse_percentile  # the solver library, needed only when a fit starts

        params["rho_d"] = diffuse_percentile(f_r, valid, 10.0)
        if not self.lobes:
            return params
        magnitudes = self._lobe_magnitudes()
        scored = []
        for log_n in np.log(START_EXPONENTS):  # each scored by its solve's own pass (its cost, exact)
            x, cost = solve_linear(self, self.pack({**params, "log_exponent_1": np.full((T, 1), log_n)}), magnitudes,
                                   f_r, np.asarray(valid, np.float64), wi, wo, with_cost=True)
            scored.append((x, np.nan_to_num(cost, nan=np.inf)))
        best, best_cost = scored[0]
        for x, cost in scored[1:]:  # the first lowest cost wins a tie, as it did when scanned in order
            better = cost < best_cost
            best[better], best_cost[better] = x[better], cost[better]
        return self.unpack(best)

    def refine_linear(self, params, f_r, valid, wi, wo):
        """ρ_s of every lobe by least squares with ρ_d and the lobe shapes held, clipped to ≥ 0: by the fit kernel
        (``engine.solve_linear``); :func:`solve_magnitudes` is the NumPy reference."""
        if not self.lobes:
            return dict(params)
        if not (f_r.shape[0] and f_r.shape[1]):
            return {**params, **solve_magnitudes(self, params, f_r, valid, wi, wo)}
        from sbrdf_core.engine import solve_linear

        solved = self.unpack(solve_linear(self, self.pack(params), self._lobe_magnitudes(), f_r, valid, wi, wo))
        return {**params, **{f"rho_s_{j}": solved[f"rho_s_{j}"] for j in range(1, self.lobes + 1)}}

    def _lobe_magnitudes(self) -> np.ndarray:
        """Packed mask of the lobes' ρ_s: the parameters f_r is affine in that :meth:`refine_linear` solves."""
        where, free = self.slices(), np.zeros(self.size, bool)
        for j in range(1, self.lobes + 1):
            free[where[f"rho_s_{j}"]] = True
        return free

    @property
    def project_kernel(self):
        """:func:`~sbrdf_models.lafortune_kernels.project_kernel`, :meth:`constrain` on one packed row: the fitting
        engine projects every iterate with it (None without lobes: the box is the whole projection)."""
        if not self.lobes:
            return None
        from .lafortune_kernels import project_kernel

        return project_kernel

    def project_limits(self, limits, T: int) -> np.ndarray:
        """Each texel's row of what :attr:`project_kernel` reads (``lafortune_kernels.LIMITS``), ``(T, 6)``;
        ``limits`` None: every bound off."""
        max_theta = np.pi / 2 if limits is None else limits.max_theta
        out = np.empty((T, 6))
        out[:, 4], out[:, 5] = np.sin(max_theta) ** 2, np.cos(max_theta) ** 2
        if limits is None:
            out[:, :4] = (0.0, 0.0, np.inf, -1.0)
            return out
        out[:, 0] = 0.0 if limits.peak is None else np.asarray(limits.peak, np.float64).reshape(T)
        out[:, 1] = limits.peak is not None
        out[:, 2] = np.broadcast_to(np.asarray(limits.max_cosine_exponent(), np.float64).reshape(-1), (T,))
        out[:, 3] = -1.0 if limits.growth is None else float(limits.growth)
        return out

    def constrain(self, params, limits):
        """:func:`bound_lobes` directly on the fit form (C_z = 1 already, log n)."""
        out, changed = BRDFModel.constrain(self, params, limits)
        if self.lobes:
            changed |= _apply_lobe_bounds(self, out, limits, exponent_key="log_exponent_{j}", log=True,
                                          reset_dead=False)
        return out, changed

    def random_guess(self, rng, T):
        params = super().random_guess(rng, T)
        if self.has_beta:
            params["beta"] = rng.uniform(-np.pi / 2, np.pi / 2, (T, 1))
        return params


def solve_magnitudes(model: LafortuneModel, params, f_r, valid, wi, wo) -> dict[str, np.ndarray]:
    """ρ_s per lobe by non-negative-clipped linear least squares on ``f_r − ρ_d`` with lobe shapes fixed."""
    pxx, pyy, pzz, _ = model.lobe_dots(params, wi, wo)
    w = (valid & above_horizon(wi, wo)).astype(float)
    basis = []
    for lobe in model.lobe_list(params):
        x = lobe["c_x"][:, :1] * pxx + lobe["c_y"][:, :1] * pyy + lobe["c_z"][:, :1] * pzz
        basis.append(positive_power(x, lobe["exponent"][:, :1]) * w)
    B = np.stack(basis, axis=-1)  # (T, S, L)
    resid = np.where(w[..., None] > 0, f_r - params["rho_d"][:, None, :], 0.0)
    A = B.transpose(0, 2, 1) @ B + 1e-12 * np.eye(B.shape[-1])
    rhs = B.transpose(0, 2, 1) @ resid  # (T, L, 3)
    rho = np.clip(np.linalg.solve(A, rhs), 0.0, 1e6)
    rho = np.nan_to_num(rho, nan=0.0, posinf=0.0)
    return {f"rho_s_{j + 1}": rho[:, j, :] for j in range(B.shape[-1])}
