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
from sbrdf_core.params import Param
from sbrdf_lib.lm import WEIGHTING, fit_model

logger = logging.getLogger(__name__)

MODEL = Param("model", "str", "lambert", "BRDF model to fit", extra={"plugin_category": "brdf-model"})
MODEL_PARAMS = Param("model_params", "dict", {}, "configuration of that model", extra={"params_of": "model"})
ITERATIONS = Param("iterations", "int", 200, "Levenberg-Marquardt iterations at most, per texel (a texel stops when "
                   "it converges: most need under 20; sharp lobes on grazing data take more)", bounds=(1, 10000))
TOLERANCE = Param("tolerance", "float", 1e-4, "stop a texel when its cost improves by less than this fraction",
                  bounds=(0.0, 1.0))


class LevenbergMarquardtFitter:
    """The ``lm`` fitter: batched Levenberg-Marquardt of any BRDF model, vectorised over texels."""

    params = (
        MODEL,
        MODEL_PARAMS,
        ITERATIONS,
        TOLERANCE,
        Param("damping", "float", 1e-3, "initial Marquardt damping λ", bounds=(0.0, None)),
        Param("starts", "int", 0, "LM runs per texel, from its best-scoring starting points (the model's guess and "
              "a Sobol set over typical shapes, magnitudes solved); the texel keeps its best. 0 = the model's "
              "suggestion (2 for Cook-Torrance, Phong, Ward and 3+ Lafortune lobes: 4); 1 = the guess alone",
              bounds=(0, 64)),
        Param("fixed", "list", [], "fit-form parameter names held at their initial value", item="str"),
        Param("seed", "int", 0, "seed of the Sobol starting points"),
        Param("loss", "str", "linear", "linear (least squares), or huber / soft-l1: outliers such as dust spikes "
              "are down-weighted (iteratively reweighted)", choices=["linear", "huber", "soft-l1"]),
        Param("loss_scale", "float", 0.0, "residual (sr^-1) where a robust loss turns from quadratic to linear; "
              "0 = 1.4826 x the texel's median absolute residual", bounds=(0.0, None)),
        WEIGHTING,
    )

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
