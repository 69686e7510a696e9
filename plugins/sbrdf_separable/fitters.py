"""svd / nd: Fit-node fitters that decompose one material into a ``separable`` model.

The input is a 1 × 1-texel SampledReflectance (a measured table, or a model
drawn by SampleModel): its scattered samples are interpolated onto the
factor grid (:class:`.sources.ScatteredBRDF`), decomposed by
:func:`.decompose.svd` or :func:`.decompose.nd`, and written as a
``SeparableFactors`` store at ``factors``; the ParamMaps the node writes name
the ``separable`` model with that store, so quantizers and renderers rebuild
it from the artifact alone.  The per-texel parameter, ``scale``, is 1.

For an analytic model there is no need for a graph: call
:func:`.decompose.nd` / :func:`.decompose.svd` on
:func:`.sources.model_function` directly (benchmarks/separable.py does).
"""

from __future__ import annotations

import logging
import os

import numpy as np

from sbrdf_core.nodes.fit import FitResult, rms_error

from .declarations import ND, SVD
from .decompose import nd, parameterization, svd
from .factors import ENCODINGS, check_target, save
from .sources import ScatteredBRDF

logger = logging.getLogger(__name__)

class SeparableFitter:
    """Shared by ``svd`` and ``nd``; ``method`` picks the decomposition."""

    method = ""
    model_name = "separable"
    model_config: dict

    def __init__(self, *, factors: str, parameterization: str = "gram-schmidt", map: str = "xy",  # noqa: A002
                 size: int = 32, terms: int = 1, p: float = 2.0, clamp_max: float | None = None,
                 encoding: str = "float32", neighbours: int = 4, impute: int = 1, solver: str = "arpack",
                 refine: int = 1):
        if encoding not in ENCODINGS:
            raise ValueError(f"encoding {encoding!r}: expected one of {list(ENCODINGS)}")
        if "://" in factors:
            raise ValueError(f"factors {factors!r}: the separable fitters write local paths only")
        self.factors = os.path.abspath(os.path.expanduser(factors))
        check_target(self.factors)  # fail before the decomposition, not after it
        self.parameterization, self.map = parameterization, map
        self.size, self.terms, self.p, self.clamp_max = size, terms, p, clamp_max
        self.encoding, self.neighbours, self.solver = encoding, neighbours, solver
        self.impute, self.refine = impute, refine
        self.model_config = {"factors": self.factors}
        self._registry = None

    def bind(self, registry) -> None:
        self._registry = registry

    def __getstate__(self):  # into dask tasks without the registry (a worker uses its own default one)
        return {**self.__dict__, "_registry": None}

    def decompose(self, fn, param):
        if self.method == "svd":
            return svd(fn, param, self.size, self.terms, self.clamp_max, self.solver, self.impute)
        return nd(fn, param, self.size, self.terms, self.p, self.clamp_max, self.impute, self.refine)

    def fit(self, model, f_r, valid, wi, wo, *, limits=None, rms=True, usable=False,
            initial=None) -> FitResult:  # initial: no refinement from a given start here
        T = f_r.shape[0]
        if T != 1:
            raise ValueError(f"{self.method} fitter: a separable decomposition describes one material; give a 1x1 "
                             f"SampledReflectance (MeasuredTable, or SampleModel with texels [1, 1]), got a tile of "
                             f"{T} texels")
        param = parameterization(self.parameterization, {"map": self.map}, self._registry)
        source = ScatteredBRDF(wi[0], wo[0], f_r[0], valid[0], param, self.neighbours)
        factors = self.decompose(source, param)
        factors.meta.update({"source": "scattered samples", "samples": source.samples, "neighbours": self.neighbours})
        save(factors, self.factors, self.encoding)
        model.set_factors(factors.encoded(self.encoding))
        params = {"scale": np.ones((1, 3))}
        ok = np.asarray(valid, bool)
        return FitResult(params, rms_error(model, params, f_r, ok, wi, wo), ok.sum(axis=1))


class SVDFitter(SeparableFitter):
    """Separable BRDF by truncated SVD of the sampled K² × K² matrix (one material)."""

    method = "svd"
    params = SVD


class NDFitter(SeparableFitter):
    """Separable BRDF by normalized decomposition, streamed (one material)."""

    method = "nd"
    params = ND
