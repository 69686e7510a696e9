"""lm: Levenberg–Marquardt for any BRDF model, batched over texels.

All texels of a tile are solved together: residuals ``(T, 3S)``, Jacobians
``(T, 3S, K)`` from the model (analytic where it has one), normal equations
``(T, K, K)`` solved in one batched call, and a per-texel damping λ that
shrinks on success and grows on failure (Marquardt's diagonal scaling).  Each
iteration works only on the texels still improving, so a tile costs what its
hardest texels need.  Parameters are clipped to the model's bounds.  Invalid
samples have zero weight; a texel with none keeps its initial guess and
reports 0 samples.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.nodes.fit import FitResult

#: A texel stops when λ exceeds this: no step along the gradient helps any more.
MAX_DAMPING = 1e8


class LevenbergMarquardtFitter:
    def __init__(self, model, model_params, iterations, tolerance, damping):
        self.model_name = model
        self.model_config = dict(model_params)
        self.iterations = iterations
        self.tolerance = tolerance
        self.damping = damping

    def fit(self, model, f_r, valid, wi, wo) -> FitResult:
        T = f_r.shape[0]
        w = valid.astype(np.float64)[..., None]  # (T, S, 1)
        f_r = np.where(w > 0, np.nan_to_num(f_r, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
        lo, hi = model.bounds()
        x = np.clip(model.pack(model.initial_guess(f_r, valid, wi, wo)), lo, hi)

        def residual(x, idx):
            return ((model.eval(model.unpack(x), wi[idx], wo[idx]) - f_r[idx]) * w[idx]).reshape(len(idx), -1)

        everyone = np.arange(T)
        r = residual(x, everyone)
        cost = np.einsum("ti,ti->t", r, r)
        lam = np.full(T, self.damping)
        active = valid.any(axis=1) & (cost > 0)
        eye = np.eye(x.shape[1])
        for _ in range(self.iterations):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            xa, ra = x[idx], r[idx]
            J = (model.jacobian(model.unpack(xa), wi[idx], wo[idx]) * w[idx][..., None]).reshape(idx.size, -1, x.shape[1])
            Jt = J.transpose(0, 2, 1)
            A = Jt @ J  # batched BLAS; einsum is several times slower here
            g = (Jt @ ra[..., None])[..., 0]
            diag = np.maximum(np.einsum("tkk->tk", A), 1e-12)
            step = -np.linalg.solve(A + (lam[idx, None] * diag)[:, :, None] * eye, g[..., None])[..., 0]
            x_new = np.clip(xa + step, lo, hi)
            r_new = residual(x_new, idx)
            cost_new = np.einsum("ti,ti->t", r_new, r_new)
            better = np.isfinite(cost_new) & (cost_new < cost[idx])
            gain = np.where(better, (cost[idx] - cost_new) / cost[idx], 0.0)
            x[idx] = np.where(better[:, None], x_new, xa)
            r[idx] = np.where(better[:, None], r_new, ra)
            cost[idx] = np.where(better, cost_new, cost[idx])
            lam[idx] = np.where(better, lam[idx] / 3.0, lam[idx] * 4.0)
            # Converged: an accepted step gained almost nothing, or a rejected one was
            # already negligible (round-off, not a bad direction: no need to grow λ).
            negligible = np.abs(step).max(axis=1) <= 1e-9 * np.maximum(np.abs(xa).max(axis=1), 1e-12)
            done = (better & (gain < self.tolerance)) | (~better & negligible) | (lam[idx] > MAX_DAMPING) | (cost[idx] <= 0)
            active[idx[done]] = False
        n = valid.sum(axis=1)
        rms = np.sqrt(cost / np.maximum(3 * n, 1))
        return FitResult(model.unpack(x), rms, n)
