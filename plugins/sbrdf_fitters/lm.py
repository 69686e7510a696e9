"""lm: the batched Levenberg–Marquardt fitter of any BRDF model.

The solver itself (:func:`~sbrdf_lib.lm.fit_model` and its parts) is shared
library code in :mod:`sbrdf_lib.lm`; this module is the fitter plugin around
it.
"""

from __future__ import annotations

import logging
import warnings

import numpy as np

from sbrdf_core.nodes.fit import NOT_CONVERGED, FitResult, usable_mask
from sbrdf_lib.lm import fit_model

from .declarations import LM

logger = logging.getLogger(__name__)


class LevenbergMarquardtFitter:
    """The ``lm`` fitter: batched Levenberg-Marquardt of any BRDF model, vectorised over texels."""

    params = LM

    def __init__(self, *, model: str = "lambert", model_params: dict = {}, iterations: int = 200,  # noqa: B006
                 tolerance: float = 1e-4, damping: float = 1e-3, starts: int = 0, fixed: tuple = (),
                 seed: int = 0, loss: str = "linear", loss_scale: float = 0.0, weighting: str = "shot-noise"):
        # model_params' default equals the declaration (the registry checks); it is only read, never changed.
        self.model_name = model
        self.model_config = dict(model_params)
        self.iterations, self.tolerance, self.damping = iterations, tolerance, damping
        self.starts, self.fixed, self.seed = starts, tuple(fixed), seed
        self.loss, self.loss_scale = loss, loss_scale
        self.weighting = weighting
        if model == "lafortune" and int(model_params.get("lobes", 1)) >= 3 and 0 < starts < 4:
            warnings.warn("lm: with 3 or more Lafortune lobes the fit depends on the starting point "
                          "(seed 000 §4.3.1); consider starts: 8", stacklevel=2)

    def fit(self, model, f_r, valid, wi, wo, *, limits=None, rms=True, usable=False, initial=None) -> FitResult:
        """``initial`` (model form): one LM run from it, no other starts.  ``rms`` False: no training RMS
        (``FitResult.rms`` None), for a caller that scores the fit itself
        (the Fit node): with a weighted objective it is a further pass over the samples.  ``usable`` True: the
        samples are :func:`~sbrdf_core.nodes.fit.usable`'s already (the Fit node's), not tested again."""
        # fit_model drops the unusable samples itself
        n = (np.asarray(valid, bool) if usable else usable_mask(f_r, valid)).sum(axis=1)
        stats: dict = {}
        start = None if initial is None else model.fit_form().from_model(initial)
        params, converged, cost = fit_model(model, f_r, valid, wi, wo, initial=start, iterations=self.iterations,
                                            tolerance=self.tolerance, damping=self.damping, fixed=self.fixed,
                                            starts=self.starts if start is None else 1, seed=self.seed,
                                            limits=limits, loss=self.loss,
                                            loss_scale=self.loss_scale, stats=stats,
                                            weighting=self.weighting, want_cost=rms, checked=usable)
        flags = np.where(converged, 0, NOT_CONVERGED).astype(np.uint8)
        # The fit's own cost: no second evaluation.
        train_rms = None if cost is None else np.sqrt(cost / np.maximum(f_r.shape[-1] * n, 1))
        return FitResult(params, train_rms, n, flags, restarted=stats.get("restarted"))
