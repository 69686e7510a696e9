"""The BRDF-model protocol every model plugin implements.

A model declares its per-texel parameters once (:class:`ModelParameter`),
evaluates vectorised over texels × direction pairs × RGB in NumPy, and may
supply an analytic Jacobian and a GLSL function.  Fitters, quantizers and
renderers work with any model through this protocol alone.

Shapes: ``params[name]`` is ``(T, C)`` (C = 1 or 3 channels); ``wi``, ``wo``
are ``(T, S, 3)`` unit vectors in the surface frame (+z the normal); ``eval``
returns ``f_r`` as ``(T, S, 3)`` in sr⁻¹.  Directions below the horizon give
zero, never NaN.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np


@dataclass(frozen=True)
class ModelParameter:
    """One parameter of a BRDF model.

    Parameters
    ----------
    name
        Spelled out from the seeds' vocabulary: ``rho_d``, ``rho_s``, ``c_x``, ``exponent``.
    channels
        3 for a per-colour-channel value (``rho_d``), 1 for a shared one (lobe shape).
    bounds
        Physically valid ``(low, high)``, enforced by fitters.
    typical
        A range seen on real materials: used to synthesise test materials and
        as the default quantization range.
    default
        Value a fitter starts from and uses for texels with no valid samples.
    scope
        ``"texel"`` (a map) or ``"global"`` (one value for the material).
    magnitude
        f_r is affine in this parameter (ρ_d, ρ_s, F0): scaling it scales the
        reflected energy, and a linear solve can find it for fixed lobe shapes
        (:meth:`BRDFModel.refine_linear`, the energy bound in :mod:`sbrdf_core.constraints`).
    """

    name: str
    channels: int = 1
    bounds: tuple[float, float] = (-np.inf, np.inf)
    typical: tuple[float, float] = (0.0, 1.0)
    default: float = 0.0
    scope: str = "texel"
    unit: str = ""
    doc: str = ""
    magnitude: bool = False


class BRDFModel:
    """Base class of BRDF-model implementations.

    Subclasses set ``name``, ``params`` (the configuration, :class:`~sbrdf_core.params.Param`)
    and ``parameters`` (the per-texel maps; per instance when the
    configuration changes them, e.g. one ``c_x`` per lobe) and implement
    :meth:`eval`; the default :meth:`jacobian` uses central differences.
    """

    #: The registered name (a fit form: the model's with ``-fit-form``).
    name: str = ""
    #: The model's configuration (``model_params``: lobes, anisotropic, ...), as keyword arguments of ``__init__``.
    params: ClassVar[tuple] = ()
    parameters: tuple[ModelParameter, ...] = ()
    #: Whether f_r depends on the azimuth of the tangent frame, not only on relative azimuth.  Renderers skip
    #: per-pixel tangent frames for models that set it False; the safe default is True.
    anisotropic: bool = True
    #: LM runs per texel when a fitter's ``starts`` is 0 (auto): more than one where the model's cost has local
    #: minima a single good guess can miss (Cook–Torrance, Phong and Ward did on 3–7 of 64 texels with one).
    suggested_starts: int = 2
    #: Width parameters (microfacet or Ward slopes, in the model form) no narrower than the sampling resolves
    #: (``limits.min_roughness()``).
    roughness: tuple[str, ...] = ()
    #: True where :meth:`constrain` is the default clip, the :attr:`roughness` floor and the roughness widened until
    #: the mirror peak fits, and nothing else (:class:`~sbrdf_core.constraints.WidenedRoughness`): the fitting
    #: engine then holds every bound inside its loop.
    widens_to_peak: bool = False
    #: Cosine-lobe exponents: none sharper than the sampling resolves (``limits.max_cosine_exponent()``).
    sharpness: tuple[str, ...] = ()

    # -- required ---------------------------------------------------------------

    def eval(self, params: Mapping[str, np.ndarray], wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``f_r(wi, wo)`` per texel and sample, ``(T, S, 3)`` sr⁻¹."""
        raise NotImplementedError

    # -- optional ---------------------------------------------------------------

    def jacobian(self, params: Mapping[str, np.ndarray], wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``∂f_r/∂x`` as ``(T, S, 3, K)`` for the packed parameter vector x (see :meth:`pack`).

        Default: central finite differences; models override with analytic forms.
        """
        x = self.pack(params)
        T, K = x.shape
        out = np.empty(wi.shape[:2] + (3, K))
        scale = np.maximum(np.abs(x), 1e-3)
        lo, hi = self.bounds()
        for k in range(K):
            h = 1e-4 * scale[:, k]
            xp, xm = x.copy(), x.copy()
            xp[:, k] = np.minimum(x[:, k] + h, hi[k])
            xm[:, k] = np.maximum(x[:, k] - h, lo[k])
            span = (xp[:, k] - xm[:, k])
            span = np.where(span > 0, span, 1.0)
            out[..., k] = (self.eval(self.unpack(xp), wi, wo) - self.eval(self.unpack(xm), wi, wo)) / span[:, None, None]
        return out

    def glsl(self) -> str:
        """GLSL source of ``vec3 brdf_<name>(vec3 wi, vec3 wo, <parameters>)`` for the GL renderer.

        Directions are in the local surface frame (z = normal, x = tangent); by
        default the parameters follow ``parameters`` in order, ``vec3`` for
        three channels and ``float`` for one (see :meth:`glsl_call`).
        """
        raise NotImplementedError(f"model {self.name!r} supplies no GLSL")

    def glsl_call(self, wi: str, wo: str, args: Mapping[str, str]) -> str:
        """A GLSL expression for f_r(wi, wo), given each parameter's GLSL expression by name.

        Renderers fetch parameters from textures however they store them and
        call the model through this; override it when :meth:`glsl` takes its
        arguments in another shape (Lafortune's per-lobe arrays).
        """
        fn = "brdf_" + self.name.replace("-", "_")
        return f"{fn}({wi}, {wo}, " + ", ".join(args[p.name] for p in self.parameters) + ")"

    @property
    def kernel(self):
        """This fit form's compiled ``fit_kernel``, or None: a model whose fit form is itself declares it."""
        return getattr(self, "fit_kernel", None)

    def kernel_config(self) -> np.ndarray:
        """The configuration a compiled ``fit_kernel`` reads, as float64 numbers (flags, choices).

        A model that declares ``fit_kernel`` (a numba function computing f_r and
        its Jacobian in the fit form at one direction pair) and has options that
        change its mathematics returns them here; default: none.
        """
        return np.zeros(0)

    def fit_form(self) -> BRDFModel:
        """An equivalent, better-conditioned parametrisation for fitters (default: ``self``).

        Fitters iterate in the fit form and convert with :meth:`to_model` /
        :meth:`from_model` of the returned object.  Lafortune lobes, for
        example, trade ρ_s against |C|^n; their fit form fixes C_z = 1 and
        fits log n, which removes the degeneracy and evens out the scales.
        """
        return self

    def to_model(self, params: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Fit-form parameters -> the model's own (identity unless :meth:`fit_form` differs)."""
        return dict(params)

    def from_model(self, params: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The model's parameters -> fit form (inverse of :meth:`to_model` up to equivalences)."""
        return dict(params)

    def limit_box(self, limits, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The part of ``limits`` a box holds, for a model that is its own fit form: ρ_d at most the peak (``lo``,
        ``hi`` ``(T, K)``, returned tightened).  The fitting engine iterates inside it."""
        where = self.slices()
        if limits.peak is not None and "rho_d" in where:
            cap = np.asarray(limits.peak, np.float64).reshape(-1, 1)
            hi[:, where["rho_d"]] = np.minimum(hi[:, where["rho_d"]], cap)
        return np.minimum(lo, hi), hi

    def peak_widths(self) -> np.ndarray | None:
        """What the fitting engine widens to hold the peak bound in its loop: nothing (an empty array) for a model
        that is its own fit form and keeps the default :meth:`constrain`, which :meth:`limit_box` holds whole;
        None where ``constrain`` holds more (it is then projected after the loop)."""
        return np.zeros(0, np.int64) if type(self).constrain is BRDFModel.constrain else None

    def canonical(self, params: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One representative of each class of equivalent parameter sets, for comparing fits."""
        return dict(params)

    def initial_guess(self, f_r: np.ndarray, valid: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> dict[str, np.ndarray]:
        """Starting parameters for a fit (default: each parameter's ``default``)."""
        return self.defaults(f_r.shape[0])

    def random_guess(self, rng: np.random.Generator, T: int) -> dict[str, np.ndarray]:
        """Random parameters within each parameter's ``typical`` range (test materials; fitters start from
        Sobol points over the same ranges, ``sbrdf_lib.lm.candidate_starts``)."""
        return {p.name: rng.uniform(p.typical[0], p.typical[1], (T, p.channels)) for p in self.parameters}

    def least_squares(self, f_r: np.ndarray, weight: np.ndarray, wi: np.ndarray, wo: np.ndarray):
        """The fitting problem for this parametrisation (see :mod:`sbrdf_core.least_squares`).

        Override to supply a compiled kernel for the normal equations.
        """
        from .least_squares import LeastSquaresProblem

        return LeastSquaresProblem(self, f_r, weight, wi, wo)

    def refine_linear(self, params, f_r, valid, wi, wo) -> dict[str, np.ndarray]:
        """Re-solve the ``magnitude`` parameters (f_r is affine in them) with the lobe shapes fixed.

        Multi-start fitting draws the nonlinear shape at random; solving the
        magnitudes for it puts each start near the data.  The default works for
        any model whose RGB magnitudes act per channel: it probes the affine
        basis with :meth:`eval` and solves a small least-squares system per
        texel and channel, clipped to the declared bounds.
        """
        mags = [p for p in self.parameters if p.magnitude and p.channels == 3]
        out = {k: np.array(v, dtype=np.float64) for k, v in params.items()}
        if not mags:
            return out
        form = self.fit_form()
        if getattr(form, "kernel", None) is not None and f_r.shape[0] and f_r.shape[1]:
            # The same system by the fit kernel: one pass over the samples, compiled, where this one evaluates
            # the model once per magnitude and more.  Magnitudes are the same numbers in both forms.
            from .engine import solve_linear

            x = form.pack(form.from_model(out))
            where = form.slices()
            free = np.zeros(form.size, bool)
            for p in mags:
                free[where[p.name]] = True
            solved = form.to_model(form.unpack(solve_linear(form, x, free, f_r, valid, wi, wo)))
            return {**out, **{p.name: np.asarray(solved[p.name], np.float64) for p in mags}}
        T = f_r.shape[0]
        zero = {**out, **{p.name: np.zeros((T, 3)) for p in mags}}
        with np.errstate(all="ignore"):
            offset = evaluate(self, zero, wi, wo)
            basis = np.stack([evaluate(self, {**zero, p.name: np.ones((T, 3))}, wi, wo) - offset for p in mags], axis=-1)
        w = np.asarray(valid, np.float64)[..., None, None] * np.isfinite(basis).all(axis=-1, keepdims=True)
        basis = np.nan_to_num(basis) * w  # (T, S, 3, P)
        rhs = np.einsum("tscp,tsc->tcp", basis, np.nan_to_num(f_r - offset) * w[..., 0])
        A = np.einsum("tscp,tscq->tcpq", basis, basis)
        A += (1e-12 * np.einsum("tcpp->tc", A)[..., None, None] + 1e-30) * np.eye(len(mags))
        with np.errstate(all="ignore"):
            sol = np.nan_to_num(np.linalg.solve(A, rhs[..., None])[..., 0])  # (T, 3, P)
        for k, p in enumerate(mags):
            out[p.name] = np.clip(sol[..., k], *p.bounds)
        return out

    def albedo_bound(self, params) -> np.ndarray | None:
        """A cheap upper bound on each texel's directional albedo over every ω_i and channel, ``(T,)``, or None.

        The energy bound integrates by quadrature only the texels this does
        not already clear (default: None, every texel is integrated).
        """
        return None

    def constrain(self, params, limits) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Project parameters into the set that keeps this model physical and bounded.

        ``limits`` (:class:`sbrdf_core.constraints.Limits`) gives per texel the
        largest f_r the data supports and the finest angular detail it
        resolves.  Returns ``(params, changed)`` with ``changed`` a ``(T,)``
        mask of the texels the projection moved.  Fitters call it on every
        iteration (in the fit form), the Fit node once more on what any fitter
        returns.  Default: clip to the declared bounds and ρ_d to the peak
        bound; models whose lobes can grow without bound (Lafortune) or resolve
        finer than the sampling (exponents, roughness: see
        :class:`~sbrdf_core.constraints.WidenedRoughness`) override it.
        """
        out: dict[str, np.ndarray] = {}
        changed = np.zeros(0, bool)  # a model without parameters: nothing to move
        for p in self.parameters:
            v = np.asarray(params[p.name], dtype=np.float64)
            c = np.clip(v, *p.bounds)
            moved = (c != v).any(axis=-1)
            changed = moved if changed.size == 0 else changed | moved
            out[p.name] = c
        out.update({k: v for k, v in params.items() if k not in out})
        if limits.peak is not None and "rho_d" in out:  # no diffuse term brighter than any lobe may be
            cap = np.asarray(limits.peak, np.float64)[:, None]
            changed = changed | (out["rho_d"] > cap).any(axis=-1)
            out["rho_d"] = np.minimum(out["rho_d"], cap)
        return out, changed

    def defaults(self, T: int) -> dict[str, np.ndarray]:
        """Every parameter at its declared default, for ``T`` texels."""
        return {p.name: np.full((T, p.channels), p.default, dtype=np.float64) for p in self.parameters}

    # -- packing ------------------------------------------------------------------

    @property
    def size(self) -> int:
        """Length of the packed per-texel parameter vector."""
        return sum(p.channels for p in self.parameters)

    def slices(self) -> dict[str, slice]:
        out, i = {}, 0
        for p in self.parameters:
            out[p.name] = slice(i, i + p.channels)
            i += p.channels
        return out

    def pack(self, params: Mapping[str, np.ndarray]) -> np.ndarray:
        """Dict of ``(T, C)`` arrays -> ``(T, K)``."""
        return np.concatenate([np.asarray(params[p.name], dtype=np.float64).reshape(-1, p.channels) for p in self.parameters], axis=1)

    def unpack(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """``(T, K)`` -> dict of ``(T, C)`` views."""
        return {name: x[:, s] for name, s in self.slices().items()}

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Packed lower and upper bounds, ``(K,)`` each."""
        lo = np.concatenate([np.full(p.channels, p.bounds[0], float) for p in self.parameters])
        hi = np.concatenate([np.full(p.channels, p.bounds[1], float) for p in self.parameters])
        return lo, hi

    def describe(self) -> list[dict]:
        """JSON declaration of the parameters, stored with ParamMaps so they decode without the plugin."""
        return [
            {"name": p.name, "channels": p.channels, "bounds": [float(b) for b in p.bounds],
             "typical": list(p.typical), "default": p.default, "scope": p.scope, "unit": p.unit}
            for p in self.parameters
        ]


class LogFitForm(BRDFModel):
    """``model`` with the named positive parameters fitted as their logarithms (``log_<name>``).

    Shared by the models whose shape parameter spans decades (Phong n, Ward
    and Cook–Torrance α): the Jacobian column of log p is p times that of p,
    which evens out the scales a damped least-squares step sees.
    """

    def __init__(self, model: BRDFModel, log_names: Iterable[str]):
        self.model, self.log_names = model, tuple(log_names)
        self.name = f"{model.name}-fit-form"
        self.parameters = tuple(self._log_param(p) if p.name in self.log_names else p for p in model.parameters)

    @staticmethod
    def _log_param(p: ModelParameter) -> ModelParameter:
        log = lambda v: float(np.log(v))  # noqa: E731
        return ModelParameter(f"log_{p.name}", p.channels, (log(p.bounds[0]), log(p.bounds[1])),
                              (log(p.typical[0]), log(p.typical[1])), log(p.default), p.scope,
                              unit=f"log {p.unit}".strip(), doc=f"log of {p.name}")

    def to_model(self, params):
        out = {k: np.asarray(v) for k, v in params.items()}
        for name in self.log_names:
            out[name] = np.exp(out.pop(f"log_{name}"))
        return out

    def from_model(self, params):
        out = {k: np.asarray(v) for k, v in params.items()}
        bounds = {p.name: p.bounds for p in self.model.parameters}
        for name in self.log_names:
            out[f"log_{name}"] = np.log(np.clip(out.pop(name), *bounds[name]))
        return out

    def eval(self, params, wi, wo):
        return self.model.eval(self.to_model(params), wi, wo)

    def jacobian(self, params, wi, wo):
        model_params = self.to_model(params)
        J = self.model.jacobian(model_params, wi, wo)
        slices = self.model.slices()
        for name in self.log_names:
            J[..., slices[name]] *= np.asarray(model_params[name])[:, None, None, :]
        return J

    def glsl(self) -> str:
        return self.model.glsl()

    @property
    def kernel(self):
        """The wrapped model's compiled ``fit_kernel`` (it works in this fit form), or None."""
        return getattr(self.model, "fit_kernel", None)

    def kernel_config(self) -> np.ndarray:
        return self.model.kernel_config()

    @property
    def project_kernel(self):
        """The wrapped model's ``project_kernel`` (its ``constrain`` on one packed row of this form), or None."""
        return getattr(self.model, "project_kernel", None)

    def project_limits(self, limits, T: int) -> np.ndarray:
        # read only where project_kernel is set, and a model with one has this too (the contract's pair)
        return self.model.project_limits(limits, T)  # type: ignore[attr-defined]

    def canonical(self, params):
        return self.from_model(self.model.canonical(self.to_model(params)))

    def limit_box(self, limits, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The part of ``limits`` a box holds, in this form: ρ_d at most the peak, and the sharpness the samples
        resolve, as a floor on the model's ``roughness`` parameters (``limits.min_roughness()``) and a cap on its
        ``sharpness`` ones (``limits.max_cosine_exponent()``).  The fitting engine iterates inside it (``lo``,
        ``hi`` are ``(T, K)``, returned tightened); the peak's widening it holds too where :meth:`peak_widths`
        says how, else it is projected afterwards."""
        where = self.slices()
        lo, hi = BRDFModel.limit_box(self, limits, lo, hi)
        if limits.resolution is None:
            return lo, hi
        for name in self.model.roughness:
            k = where[f"log_{name}"] if f"log_{name}" in where else where[name]
            floor = np.asarray(limits.min_roughness(), np.float64)
            lo[:, k] = np.maximum(lo[:, k], np.log(floor) if f"log_{name}" in where else floor)
        for name in self.model.sharpness:
            k = where[f"log_{name}"] if f"log_{name}" in where else where[name]
            cap = np.asarray(limits.max_cosine_exponent(), np.float64)
            hi[:, k] = np.minimum(hi[:, k], np.log(cap) if f"log_{name}" in where else cap)
        return np.minimum(lo, hi), hi

    def peak_widths(self) -> np.ndarray | None:
        """Packed indices of the log roughness parameters, where :meth:`limit_box` and widening them to the peak
        are the whole of the model's ``constrain`` (``widens_to_peak``): the fitting engine then holds every
        bound inside its loop.  None otherwise."""
        if not self.model.widens_to_peak:
            return None
        where = self.slices()
        if not all(f"log_{n}" in where for n in self.model.roughness):
            return None
        return np.array([where[f"log_{n}"].start for n in self.model.roughness], np.int64)

    def initial_guess(self, f_r, valid, wi, wo):
        return self.from_model(self.model.initial_guess(f_r, valid, wi, wo))

    def refine_linear(self, params, f_r, valid, wi, wo):
        return self.from_model(self.model.refine_linear(self.to_model(params), f_r, valid, wi, wo))

    def constrain(self, params, limits):
        out, changed = self.model.constrain(self.to_model(params), limits)
        return self.from_model(out), changed

    def fit_form(self):
        return self


def positive_power(x: np.ndarray, exponent: np.ndarray) -> np.ndarray:
    """``max(0, x)^exponent`` that never overflows, NaNs or warns.

    Negative generalized dot products raised to a fractional power are
    undefined (seed 000 notes §7.1): they give 0.  The result is capped at
    e^LOG_CAP so |C·ω|^n with |C| > 1 and n = 10⁴ stays finite.
    """
    pos = x > 0
    logx = np.log(np.where(pos, x, 1.0))
    return np.where(pos, np.exp(np.clip(exponent * logx, -745.0, LOG_CAP)), 0.0)


#: Cap on log f in :func:`positive_power` (e^60 ≈ 1e26 sr⁻¹: beyond any measurement).
LOG_CAP = 60.0


def luminance_weights(colour_space: str = "mcallister") -> np.ndarray:
    """Linear-RGB -> luminance weights of a working colour space.

    ``mcallister`` is seed 000 Eq 2.3 (his camera's RGB primaries; sums to
    0.9999); ``rec709`` is linear sRGB / Rec. 709.
    """
    try:
        return np.array(LUMINANCE_WEIGHTS[colour_space])
    except KeyError:
        raise ValueError(f"unknown colour space {colour_space!r}; known: {', '.join(LUMINANCE_WEIGHTS)}") from None


LUMINANCE_WEIGHTS = {
    "mcallister": (0.2582, 0.6566, 0.0851),
    "rec709": (0.2126, 0.7152, 0.0722),
    "rec2020": (0.2627, 0.6780, 0.0593),
}


def evaluate(model: BRDFModel, params: Mapping[str, np.ndarray], wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``model.eval``, compiled from the model's fit kernel where it has one and the batch is large
    (:func:`sbrdf_core.engine.evaluate`): what the bounds, the energy check and the Fit node's scoring call.
    ``eval`` stays the reference the kernel is tested against."""
    from .engine import evaluate as compiled

    out = compiled(model, params, wi, wo)
    return model.eval(params, wi, wo) if out is None else out


def above_horizon(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``(T, S)`` mask of direction pairs where both are above the surface."""
    return (wi[..., 2] > 0) & (wo[..., 2] > 0)
