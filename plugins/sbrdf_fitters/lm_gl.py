"""lm-gl: the ``lm`` fitter's batched Levenberg–Marquardt, each texel's iterations in a compute shader.

What stays on the CPU is what ``lm`` does once per texel: the starting
points (the model's initial guess, Sobol starts scored by cost, exactly as
:func:`sbrdf_lib.lm.fit_model` chooses them, projected onto the limits),
robust-loss weights between IRLS rounds, and a last float64 projection onto
the plausibility limits.  For a model with the optional
``glsl_fit_constrain`` the shader projects the start and every trial point
onto the texel's :class:`~sbrdf_core.constraints.Limits` itself, so the
constrained fit is ``lm``'s step for step in one shader loop (chunked over a
few dispatches, :func:`.lm_gl_shader.chunk`).  For a model without it, a first
pass fits every texel inside the fit form's box bounds; a texel whose result
leaves its limits is fitted again from ``lm``'s starts *stepwise*
(:func:`.lm_gl_device.run_stepwise`: the GPU proposes each trial point, the CPU
projects it, the GPU evaluates it); with ``loss`` huber / soft-l1 such
texels are refitted by ``lm``'s own solver on the CPU.

Float32: the fit form already fits log exponents / log roughness; residuals
are divided by each texel's RMS sample value, so costs are O(1) whatever
the material's brightness.  A texel still unconverged after ``iterations``
(``lm`` leaves as many so) gets another ``iterations`` on the GPU from where
it stopped, and what is left is finished in float64 on the CPU
(``cpu_finish``); with ``cpu_finish: false`` it is flagged
``NOT_CONVERGED`` as ``lm`` flags it.  Non-finite results fall back to the
starting point, flagged, never NaN.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from sbrdf_core.constraints_glsl import pack_limits, scalars
from sbrdf_core.contracts import optional
from sbrdf_core.engine_glsl import fit_gradient_glsl
from sbrdf_core.errors import SbrdfError
from sbrdf_core.nodes.fit import NOT_CONVERGED, FitResult
from sbrdf_core.nodes.fit import usable as usable_samples
from sbrdf_lib.lm import (
    IRLS_ROUNDS,
    LOSSES,
    fit_model,
    keep_better,
    least_squares,
    projector,
    rescue,
    robust_weights,
    sample_weights,
    starting_points,
    total_cost,
)
from sbrdf_lib.lm_params import WEIGHTINGS

from . import lm_gl_device, lm_gl_shader
from .declarations import LM_GL

logger = logging.getLogger(__name__)

#: Exact fit, relative to the (scaled) data energy: what float32 cost sums can tell from zero.
EXACT32 = 1e-12


def gradient_glsl(model) -> str:
    """``brdf_fit_gradient`` translated from the model's fit kernel (:mod:`sbrdf_core.engine_glsl`), or an error
    naming the model."""
    glsl = fit_gradient_glsl(model)
    if glsl is None:
        raise SbrdfError(f"lm-gl: model {getattr(model, 'name', type(model).__name__)!r} has no GLSL fit gradient "
                         "(it is translated from a fit_kernel, which the model lacks); fit it with the lm fitter")
    return glsl


@dataclass
class _Device:
    """LM on the GPU for a set of texels: every trial point projected in the shader (``constrained``), or by a
    ``project`` on the CPU (stepwise); costs come back in sr⁻² (residuals are scaled by each texel's RMS,
    ``scale``, on the device)."""

    src: str
    f_r: np.ndarray
    wi: np.ndarray
    wo: np.ndarray
    scale: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    free: np.ndarray
    max_step: np.ndarray | None
    packed: tuple | None
    tile: int
    tolerance: float
    damping: float
    timings: dict
    in_shader: bool

    def __call__(self, x, weight, iterations, idx, project=None, constrained=None):
        """Texels ``idx`` from ``x`` (``weight``: their rows) for up to ``iterations``: ``(x, cost, converged)``."""
        constrained = self.in_shader if constrained is None else constrained
        w = weight / self.scale[idx, None]
        status = (~(w > 0).any(axis=1)).astype(np.float32)
        fw = self.f_r[idx] * w[..., None]
        exact = EXACT32 * np.einsum("tsc,tsc->t", fw, fw)
        opts = dict(lo=self.lo, hi=self.hi, free=self.free, iterations=iterations, tolerance=self.tolerance,
                    damping=self.damping, timings=self.timings, max_step=self.max_step)
        if project is None:
            lim = (self.packed[0][idx], self.packed[1], self.packed[2]) if constrained and self.packed else None
            x, cost, converged, _ = lm_gl_device.call(lm_gl_device.run_tiles, self.src, x, status, exact,
                                                      self.f_r[idx], w, self.wi[idx], self.wo[idx], tile=self.tile,
                                                      limits=lim, **opts)
        else:
            x, cost, converged, _ = lm_gl_device.call(lm_gl_device.run_stepwise, self.src, x, status, exact,
                                                      self.f_r[idx], w, self.wi[idx], self.wo[idx], project=project,
                                                      **opts)
        return x, cost * self.scale[idx] ** 2, converged


class GLLevenbergMarquardtFitter:
    """The ``lm-gl`` fitter: ``lm``'s fit, with the per-texel iterations in OpenGL compute shaders."""

    params = LM_GL

    def __init__(self, *, model: str = "lambert", model_params: dict = {}, iterations: int = 200,  # noqa: B006
                 tolerance: float = 1e-4, damping: float = 1e-3, starts: int = 0, fixed: tuple = (),
                 seed: int = 0, loss: str = "linear", loss_scale: float = 0.0, tile: int = 4096,
                 cpu_finish: bool = True, weighting: str = "shot-noise"):
        self.model_name = model
        self.model_config = dict(model_params)
        self.iterations, self.tolerance, self.damping = iterations, tolerance, damping
        self.starts, self.fixed, self.seed = starts, tuple(fixed), seed
        self.loss, self.loss_scale, self.tile, self.cpu_finish = loss, loss_scale, tile, cpu_finish
        self.weighting = weighting
        #: Seconds per stage since construction (starts, upload, compute = dispatch and read-back, polish: the CPU
        #: part) and texel counts (texels, cpu_texels: finished or refitted on the CPU).
        self.timings: dict[str, float] = {}

    def bind(self, registry) -> None:
        """Refuse a model without a GLSL fit gradient when the graph is built, not at the first tile."""
        gradient_glsl(registry.create("brdf-model", self.model_name, dict(self.model_config)))

    def fit(self, model, f_r, valid, wi, wo, *, limits=None, rms=True, usable=False, initial=None) -> FitResult:
        """``initial`` (model form): one LM run from it, no other starts."""
        self._check()
        glsl = gradient_glsl(model)
        t0 = time.perf_counter()
        f_r, valid = usable_samples(f_r, valid)
        form = model.fit_form()
        T = f_r.shape[0]
        lo, hi = form.bounds()
        max_step = optional(form, "max_step", "brdf-model")
        free = self._free(form)
        project = projector(form, limits)
        everyone = np.arange(T)
        src, in_shader = self._shader(model, form, glsl, project is not None)
        packed = (pack_limits(limits, T), *scalars(limits)) if in_shader else None
        plain_weight = valid.astype(np.float64)
        base = sample_weights(f_r, valid, WEIGHTINGS[self.weighting])  # lm's objective: sbrdf_lib.lm.fit_model
        start = None if initial is None else form.from_model(initial)
        starts = 1 if start is not None else self.starts or model.suggested_starts
        x_starts = starting_points(form, least_squares(form, f_r, base, wi, wo), f_r, valid, wi,
                                   wo, starts, self.seed, start, free, project)
        n = valid.sum(axis=1)
        energy = np.einsum("tsc,tsc->t", f_r, f_r)
        scale = np.maximum(np.sqrt(energy / np.maximum(3 * n, 1)), 1e-6)  # residuals in units of the texel's RMS
        self._add("starts_s", time.perf_counter() - t0)

        gpu = _Device(src, f_r, wi, wo, scale, lo, hi, free, max_step, packed, self.tile, self.tolerance, self.damping,
                      self.timings, in_shader)

        def descend(x0, idx=everyone):
            return self._descend(gpu, form, f_r, valid, wi, wo, base, x0, idx)

        best = None
        for x0 in x_starts:
            xs, cs, conv = descend(x0)
            best = keep_better(best, xs, cs, conv, 1e-6)  # float32 costs: a coarser margin than lm's
        assert best is not None
        if project is None or in_shader:
            best = rescue(form, best, f_r, valid, wi, wo, base, self.seed, free, limits, descend, 1e-6)
        x, cost, converged, restarted = best
        if project is not None and self.loss == "linear" and not in_shader:
            self._stepwise(form, gpu, project, limits, x_starts, base, x, cost, converged)
        if self.cpu_finish and self.loss == "linear" and (project is None or in_shader):
            # Texels still improving after `iterations` (lm leaves as many unconverged): another `iterations` on the
            # GPU from where they stopped, as the CPU finish would run them; only what is left goes to the CPU.
            late = np.flatnonzero(~converged)
            if late.size:
                x[late], cost[late], converged[late] = gpu(x[late], base[late], self.iterations, late)
            self._add("gpu_finish_texels", late.size)
        x, cost, converged = self._polish(model, form, x, cost, converged, f_r, valid, wi, wo, lo, hi, free, limits,
                                          None if in_shader else project, everyone)
        if project is not None:  # float32 round-off can leave a bound by an ulp: project once more in float64
            x = project(x, everyone)
        if self.weighting != "absolute":  # the unweighted cost, whatever was minimised (a robust loss's already is)
            cost = total_cost(least_squares(form, f_r, plain_weight, wi, wo), x)
        flags = np.where(converged, 0, NOT_CONVERGED).astype(np.uint8)
        rms = np.sqrt(np.maximum(cost, 0.0) / np.maximum(f_r.shape[-1] * n, 1))
        return FitResult(form.to_model(form.unpack(x)), rms, n, flags, restarted=restarted)

    def _check(self) -> None:
        if self.loss not in LOSSES:
            raise ValueError(f"lm-gl: loss {self.loss!r} is not one of {', '.join(LOSSES)}")
        if self.weighting not in WEIGHTINGS:
            raise ValueError(f"lm-gl: weighting {self.weighting!r} is not one of {', '.join(WEIGHTINGS)}")

    @staticmethod
    def _shader(model, form, glsl: str, limited: bool) -> tuple[str, bool]:
        """The compute shader's source, and whether it projects every trial point onto the limits itself (a model
        with ``glsl_fit_constrain``, where there are ``limited``) rather than the CPU, stepwise."""
        constrain = optional(model, "glsl_fit_constrain", "brdf-model") if limited else None
        widths = getattr(form, "peak_widths", lambda: None)()
        along = constrain is not None and widths is not None and widths.size > 0  # a widening model's bound
        return lm_gl_shader.source(glsl, form.size, constrain() if constrain is not None else None, along), \
            constrain is not None

    def _descend(self, gpu, form, f_r, valid, wi, wo, base, x0, idx):
        """The GPU fit of texels ``idx`` from ``x0`` (with the robust loss's reweighting); a texel float32 could
        not follow keeps its start, flagged."""
        x, weight = x0, base[idx]
        for _ in range(1 if self.loss == "linear" else IRLS_ROUNDS):
            x, cost, converged = gpu(x, weight, self.iterations, idx)
            if self.loss != "linear":
                weight = robust_weights(form, x, f_r[idx], valid[idx], wi[idx], wo[idx], self.loss,
                                        self.loss_scale) * base[idx]
        if self.loss != "linear":
            cost = gpu(x, base[idx], 0, idx, constrained=False)[1]
        broken = ~(np.isfinite(x).all(axis=1) & np.isfinite(cost))
        if broken.any():
            b = np.flatnonzero(broken)
            x[b], converged[b] = x0[b], False
            t = idx[b]
            cost[b] = np.nan_to_num(total_cost(least_squares(form, f_r[t], base[t], wi[t], wo[t]), x0[b]), nan=np.inf)
        return x, cost, converged

    def _free(self, form) -> np.ndarray:
        """``(K,)`` True where a packed parameter is fitted, False for those named in ``fixed``."""
        free = np.ones(form.size, bool)
        slices = form.slices()
        for name in self.fixed:
            if name not in slices:
                raise ValueError(f"lm-gl: fixed parameter {name!r} is not a parameter of {form.name}; "
                                 f"known: {', '.join(slices)}")
            free[slices[name]] = False
        return free

    def _stepwise(self, form, gpu, project, limits, x_starts, base, x, cost, converged) -> None:
        """A model without glsl_fit_constrain: texels whose fit left their limits get lm's constrained fit (every
        trial point projected on the CPU) on the GPU, stepwise, from the same starts; ``x``, ``cost``,
        ``converged`` updated in place."""
        t1 = time.perf_counter()
        everyone = np.arange(x.shape[0])
        moved = np.flatnonzero((np.abs(project(x, everyone) - x) > 1e-6 * (1.0 + np.abs(x))).any(axis=1))
        if moved.size:
            sub_project = projector(form, limits.take(moved))
            assert sub_project is not None  # limits are set: project is not None
            inside = None
            for x0 in x_starts:
                xs, cs, conv = gpu(x0[moved], base[moved], self.iterations, moved, lambda v, i: sub_project(v, i))
                if inside is None:
                    inside = [xs, cs, conv]
                else:
                    b = cs < inside[1] * (1 - 1e-6)
                    inside[0][b], inside[1][b], inside[2][b] = xs[b], cs[b], conv[b]
            assert inside is not None
            x[moved], cost[moved], converged[moved] = inside
        self._add("stepwise_texels", moved.size)
        self._add("stepwise_s", time.perf_counter() - t1)

    def _add(self, key: str, seconds: float) -> None:
        self.timings[key] = self.timings.get(key, 0.0) + seconds

    def _polish(self, model, form, x, cost, converged, f_r, valid, wi, wo, lo, hi, free, limits, project, everyone):
        """The CPU's share: texels still outside their limits (a robust loss, which the stepwise GPU pass does not
        reweight) are fitted again exactly as ``lm`` fits them; texels float32 left unconverged are finished in
        float64 from where the GPU stopped (``cpu_finish``)."""
        t0 = time.perf_counter()
        x, cost, converged = x.copy(), cost.copy(), converged.copy()
        moved = np.zeros(x.shape[0], bool)
        if project is not None:
            moved = (np.abs(project(x, everyone) - x) > 1e-6 * (1.0 + np.abs(x))).any(axis=1)
            idx = np.flatnonzero(moved)
            if idx.size:
                params, conv, cs = fit_model(model, f_r[idx], valid[idx], wi[idx], wo[idx], iterations=self.iterations,
                                             tolerance=self.tolerance, damping=self.damping, fixed=self.fixed,
                                             starts=self.starts, seed=self.seed, limits=limits.take(idx),
                                             loss=self.loss, loss_scale=self.loss_scale, weighting=self.weighting)
                x[idx], cost[idx], converged[idx] = form.pack(form.from_model(params)), cs, conv
        late = np.flatnonzero(~converged & ~moved) if self.cpu_finish else np.zeros(0, int)
        if late.size:
            params, conv, cs = fit_model(model, f_r[late], valid[late], wi[late], wo[late],
                                         initial=form.unpack(x[late]), iterations=self.iterations,
                                         tolerance=self.tolerance, damping=self.damping, fixed=self.fixed, starts=1,
                                         limits=None if limits is None else limits.take(late), loss=self.loss,
                                         loss_scale=self.loss_scale, weighting=self.weighting)
            x[late], cost[late], converged[late] = form.pack(form.from_model(params)), cs, conv
        cpu = int(moved.sum()) + late.size
        if cpu:
            logger.debug("lm-gl: %d of %d texels fitted or finished on the CPU", cpu, x.shape[0])
        self._add("polish_s", time.perf_counter() - t0)
        self._add("texels", x.shape[0])
        self._add("cpu_texels", cpu)
        return x, cost, converged
