"""The weighted least-squares problem a fitter hands to Levenberg–Marquardt.

A BRDF model returns one from :meth:`BRDFModel.least_squares`.  The default
below builds the normal equations from the model's NumPy ``eval`` and
``jacobian``: correct for every model, but it materialises ``(T, S, 3, K)``
Jacobians.  A model with a compiled kernel (the built-in Lafortune model
has one) returns its own problem object that accumulates ``JᵀJ`` and ``Jᵀr``
sample by sample instead; fitters cannot tell the difference.  Such an object
provides ``data_energy()`` and ``normal_equations(x, idx)``, and ``cost(x,
idx)`` where it can give the cost alone for less (the solver falls back to
``normal_equations`` without one).  It may also solve the whole
Levenberg–Marquardt iteration itself (``levenberg_marquardt(x0, bounds, *,
iterations, tolerance, damping, free, limits, exact, max_damping)``, the
compiled Lafortune problem does for isotropic lobes), returning None where
it does not apply; :func:`sbrdf_lib.lm.levenberg_marquardt` then runs its
own.

This is part of the model contract (what ``least_squares`` returns); the
solver that consumes it is library code, :mod:`sbrdf_lib.lm`.
"""

from __future__ import annotations

import numpy as np


class LeastSquaresProblem:
    """``Σ_s Σ_c (w_s (f_model − f_r))²`` per texel, for a batch of texels.

    ``f_r`` ``(T, S, C)`` data, ``weight`` ``(T, S)`` per-sample weights
    (0 = ignore), ``wi``/``wo`` ``(T, S, 3)`` directions.  Parameter vectors
    are ``(n, K)`` rows for the texels ``idx``.
    """

    def __init__(self, model, f_r, weight, wi, wo):
        self.model, self.f_r, self.wi, self.wo = model, f_r, wi, wo
        self.weight = weight[..., None].astype(np.float64)

    def data_energy(self) -> np.ndarray:
        """``Σ (w f_r)²`` per texel: the scale a cost is small against."""
        wf = self.f_r * self.weight
        return np.einsum("tsc,tsc->t", wf, wf)

    def residual(self, x: np.ndarray, idx: np.ndarray) -> np.ndarray:
        m = self.model
        with np.errstate(all="ignore"):
            pred = m.eval(m.unpack(x), self.wi[idx], self.wo[idx])
        return ((pred - self.f_r[idx]) * self.weight[idx]).reshape(len(idx), -1)

    def cost(self, x: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """``cost (n,)`` at ``x``, as :meth:`normal_equations` gives it, without the Jacobian."""
        r = self.residual(x, idx)
        return np.einsum("ti,ti->t", r, r)

    def normal_equations(self, x: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(JᵀJ (n, K, K), Jᵀr (n, K), cost (n,))`` at ``x``."""
        m = self.model
        r = self.residual(x, idx)
        J = (m.jacobian(m.unpack(x), self.wi[idx], self.wo[idx]) * self.weight[idx][..., None]).reshape(len(idx), -1, x.shape[1])
        Jt = J.transpose(0, 2, 1)
        return Jt @ J, (Jt @ r[..., None])[..., 0], np.einsum("ti,ti->t", r, r)
