"""The fitting engine: one compiled Levenberg–Marquardt for every model that has a fit kernel.

A model brings only its mathematics, as one function on its fit form::

    def fit_kernel(x, cfg, wi, wo, f, J):
        # x (K,) packed fit-form parameters, cfg (n,) from kernel_config(),
        # wi, wo (3,) directions; writes f_r (nc,) into f and d f_r / d x (nc, K) into J

and declares it as ``fit_kernel`` (with ``kernel_config()`` when it has
options).  The kernel is plain Python on scalars and ``math`` (so listing the
model imports no compiler, and the function itself runs, slowly, anywhere); the
engine compiles it with numba.  The engine does the rest, the same for every model: the normal
equations, the damped solve, bounds, step limits and convergence
(:mod:`sbrdf_core.engine_lm`), in parallel over texels without the GIL.  The peak bound is held in
the loop too: by widening the roughness of a model that declares ``widens_to_peak``
(:class:`~sbrdf_core.constraints.WidenedRoughness`), or by the form's own ``project_kernel(x, cfg, lim,
lo, hi)`` (one packed row in place, with ``project_limits(limits, T)`` giving each texel's ``lim``).  The
NumPy path (``form.eval`` / ``form.jacobian``) is the oracle a model's kernel
is tested against, and what a model without a kernel is fitted with.

Compiled once: the loops are copied per kernel into a cache directory
(``SBRDF_KERNEL_CACHE``, default ``~/.cache/sbrdf/kernels``) under a name that
hashes the template and the kernel's source, so numba's own on-disk cache is
reused by every later process and invalidated when either changes.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import logging
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

__all__ = ["CompiledProblem", "cache_dir", "compiled_problem", "evaluate", "integrate", "over_texels", "project", "solve_linear", "solver",
           "threads"]

_TEMPLATE = Path(__file__).with_name("engine_lm.py")
_MARK = "kernel: Any = None  # KERNEL: the cached copy imports the model's fit kernel on this line"
_loaded: dict[tuple[str, ...], object] = {}
_lock = threading.Lock()


def cache_dir() -> Path:
    """Where the generated solver modules (and numba's cache of them) live."""
    env = os.environ.get("SBRDF_KERNEL_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "sbrdf" / "kernels"


def _source(function, what: str) -> tuple[str, str]:
    func = getattr(function, "py_func", function)
    module, name = func.__module__, func.__qualname__
    if "." in name or "<" in name:
        raise TypeError(f"{module}.{name}: a {what} must be a module-level function (the engine imports it by name)")
    return module, name


def solver(kernel, project=None):
    """The :mod:`~sbrdf_core.engine_lm` module compiled around ``kernel`` (and the form's ``project_kernel``
    where it has one), loaded once a process."""
    module, name = _source(kernel, "fit kernel")
    pmodule, pname = _source(project, "projection kernel") if project is not None else ("", "")
    key = (module, name, pmodule, pname)
    with _lock:
        if key in _loaded:
            return _loaded[key]
        template = _TEMPLATE.read_text()
        if _MARK not in template:
            raise RuntimeError(f"{_TEMPLATE}: the KERNEL line is missing")
        jit = "njit(cache=True, nogil=True, inline='always')"
        line = (f"from {module} import {name} as _source  # KERNEL\n"
                f"kernel = {jit}(getattr(_source, 'py_func', _source))")
        sources = inspect.getsource(getattr(kernel, "py_func", kernel))
        if project is not None:
            line += (f"\nfrom {pmodule} import {pname} as _project  # KERNEL\n"
                     f"project = njit(cache=True, nogil=True)(getattr(_project, 'py_func', _project))")
            sources += inspect.getsource(getattr(project, "py_func", project))
        text = template.replace(_MARK, line)
        digest = hashlib.sha256(text.encode() + sources.encode()).hexdigest()[:16]
        stem = f"lm_{module.replace('.', '_')}_{name}_{digest}"
        folder = cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{stem}.py"
        if not path.exists():
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(text)
            os.replace(tmp, path)  # atomic: a concurrent process sees the whole file or none
        spec = importlib.util.spec_from_file_location(f"sbrdf_kernels.{stem}", path)
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod
        spec.loader.exec_module(mod)
        _loaded[key] = mod
        return mod


_POOL: ThreadPoolExecutor | None = None


def threads() -> int:
    """Threads a compiled loop runs on: every core from the main thread, one from any other.

    Why one: a worker thread's caller (dask's threaded scheduler running Fit
    tiles) is parallel already, and more threads on top of it would only
    compete for the same cores.
    """
    if threading.current_thread() is not threading.main_thread():
        return 1
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


#: Kernel calls below which a loop runs on the calling thread alone: fewer do not pay for handing out slices.
POOL_MIN_CALLS = 1 << 16


def over_texels(T: int, body, calls: int) -> None:
    """``body(a, b)`` for slices ``[a, b)`` covering ``range(T)``, on :func:`threads` threads (the loops hold no GIL);
    ``calls``: kernel calls the whole loop makes, about."""
    global _POOL
    n = threads()
    if n == 1 or T < 4 * n or calls < POOL_MIN_CALLS:
        body(0, T)
        return
    if _POOL is None or _POOL._max_workers < n:
        _POOL = ThreadPoolExecutor(n, thread_name_prefix="sbrdf-engine")
    edges = np.linspace(0, T, 4 * n + 1).astype(int)  # several slices a thread: texels differ in cost
    for f in [_POOL.submit(body, a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]:
        f.result()


def _c(a, dtype=np.float64):
    return np.ascontiguousarray(a, dtype=dtype)


def _box(form, bounds, limits, T: int) -> tuple[np.ndarray, np.ndarray]:
    """Each texel's box ``(T, K)``: ``bounds`` tightened by the part of ``limits`` the form's ``limit_box`` holds."""
    K = len(bounds[0])
    lo = np.broadcast_to(np.asarray(bounds[0], np.float64), (T, K)).copy()
    hi = np.broadcast_to(np.asarray(bounds[1], np.float64), (T, K)).copy()
    box = getattr(form, "limit_box", None)
    return box(limits, lo, hi) if limits is not None and box is not None else (lo, hi)


def _compiled(form):
    """The solver module of ``form``'s kernels (:func:`solver`) and its kernel configuration."""
    return solver(form.kernel, getattr(form, "project_kernel", None)), _c(form.kernel_config())


class CompiledProblem:
    """The least-squares problem of a fit form with a ``kernel``, for :func:`sbrdf_lib.lm.levenberg_marquardt`.

    Same interface and numbers as :class:`~sbrdf_core.least_squares.LeastSquaresProblem`
    (``Σ (w (f − f_r))²`` per texel), plus a compiled ``levenberg_marquardt``.
    """

    def __init__(self, form, f_r, weight, wi, wo):
        self.form = form
        self.f_r, self.wi, self.wo = _c(f_r), _c(wi), _c(wo)
        self.weight = _c(np.broadcast_to(weight, f_r.shape[:2]))
        self._project = getattr(form, "project_kernel", None)
        self._mod, self.cfg = _compiled(form)
        widths = getattr(form, "peak_widths", None)
        self._widths = None if widths is None else widths()
        #: Whether the compiled loop holds the whole of ``form.constrain`` (its box, and its peak widening or the
        #: form's own ``project_kernel``): if not, :func:`~sbrdf_lib.lm.levenberg_marquardt` projects onto the
        #: rest afterwards.
        self.projects = self._widths is not None or self._project is not None

    def data_energy(self) -> np.ndarray:
        wf = self.f_r * self.weight[..., None]
        return np.einsum("tsc,tsc->t", wf, wf)

    def cost(self, x, idx) -> np.ndarray:
        """The objective of texels ``idx`` at the rows of ``x``, read in place (no copy of their samples)."""
        rows = _c(idx, np.int64)
        out = np.empty(len(rows))
        x = _c(x)
        over_texels(len(rows), lambda a, b: self._mod.costs(self.cfg, x[a:b], rows[a:b], self.f_r, self.weight,
                                                            self.wi, self.wo, out[a:b]), self.f_r.shape[1] * len(rows))
        return out

    def normal_equations(self, x, idx):
        n, K = x.shape
        A, g, cost = np.empty((n, K, K)), np.empty((n, K)), np.empty(n)
        x, rows, free = _c(x), _c(idx, np.int64), np.ones(K, np.uint8)
        over_texels(n, lambda a, b: self._mod.all_normal_equations(
            self.cfg, x[a:b], rows[a:b], free, self.f_r, self.weight, self.wi, self.wo, A[a:b], g[a:b], cost[a:b]),
            n * self.f_r.shape[1])
        return A, g, cost

    def levenberg_marquardt(self, x0, bounds, *, iterations, tolerance, damping, free, limits, exact, max_damping,
                            max_step):
        """Every texel's LM in the compiled loop, inside the box the form's bounds and ``limits`` make.

        Returns ``(x, cost, converged)``.  Where the form's ``constrain`` holds more than the box, its peak
        widening and its projection kernel (``projects`` False), the caller projects the result and refines what
        moved.
        """
        T, K = x0.shape
        lo, hi = _box(self.form, bounds, limits, T)
        step = np.full(K, np.inf) if max_step is None else np.asarray(max_step, np.float64)
        x, cost, converged = np.empty((T, K)), np.empty(T), np.empty(T, np.bool_)
        used = np.empty(T, np.int64)
        x0, lo, hi, free, exact = _c(x0), _c(lo), _c(hi), _c(free, np.uint8), _c(exact * self.data_energy())
        step = _c(step)
        widths, log_bound, mi, mo, cos2 = peak_bound(self._widths, limits, T)
        projecting = self._project is not None and limits is not None
        lim = _c(self.form.project_limits(limits, T)) if projecting else np.zeros((T, 0))
        over_texels(T, lambda a, b: self._mod.solve(
            self.cfg, x0[a:b], lo[a:b], hi[a:b], free, step, self.f_r[a:b], self.weight[a:b], exact[a:b],
            self.wi[a:b], self.wo[a:b], int(iterations), float(tolerance), float(damping), float(max_damping),
            widths, log_bound[a:b], mi, mo, cos2, projecting, lim[a:b], x[a:b], cost[a:b], converged[a:b],
            used[a:b]), T * self.f_r.shape[1] * int(iterations))
        return x, cost, converged


def peak_bound(widths, limits, T: int):
    """The peak bound as the compiled loops read it: the packed indices ``widths`` they widen (None: no bound),
    each texel's log bound (inf: none), the mirror pairs and their weights (cos² θ for ``limits.peak_cosine``)."""
    from .geometry import mirror_pairs

    bound = None if limits is None or widths is None else (
        limits.peak_cosine if limits.peak_cosine is not None else limits.peak)
    if bound is None:
        none = np.zeros((0, 3))
        return np.zeros(0, np.int64), np.full(T, np.inf), none, none, np.zeros(0)
    mi, mo = mirror_pairs(limits.max_theta)
    cos2 = mi[:, 2] ** 2 if limits.peak_cosine is not None else np.ones(len(mi))
    with np.errstate(divide="ignore"):
        log_bound = np.log(np.broadcast_to(np.asarray(bound, np.float64).reshape(-1), (T,)))
    return _c(widths, np.int64), _c(log_bound), _c(mi), _c(mo), _c(cos2)


#: Direction pairs (texels × pairs) from which :func:`evaluate` runs compiled: below, NumPy costs less.
EVALUATE_MIN = 4096


def evaluate(model, params, wi, wo) -> np.ndarray | None:
    """f_r ``(T, S, C)`` of the model-form ``params`` by the model's fit kernel; None where it has none, or the batch
    is too small to pay for the call (the caller then uses ``model.eval``, the NumPy reference it equals)."""
    # The cheap tests first: the bounds' bisections call this thousands of times on batches NumPy takes.
    wi, wo = np.asarray(wi, np.float64), np.asarray(wo, np.float64)
    if wi.ndim not in (2, 3) or wo.ndim not in (2, 3) or wi.shape[-1] != 3 or wo.shape[-1] != 3 or not params:
        return None
    T = np.shape(next(iter(params.values())))[0]
    S = np.broadcast_shapes(wi.shape, wo.shape)[-2]
    if T * S < EVALUATE_MIN:
        return None
    form = model.fit_form()
    kernel = getattr(form, "kernel", None)
    if kernel is None:
        return None
    x = form.pack(params if form is model else form.from_model(params))
    wi, wo = _c(np.broadcast_to(wi, (T, S, 3))), _c(np.broadcast_to(wo, (T, S, 3)))
    out = np.empty((T, S, getattr(form, "channels", 3)))
    (mod, cfg), x = _compiled(form), _c(x)
    over_texels(T, lambda a, b: mod.evaluate(cfg, x[a:b], wi[a:b], wo[a:b], out[a:b]), T * S)
    return out


def integrate(model, params, wi, wo, weights) -> np.ndarray | None:
    """``Σ_s weights[s] f_r(ω_i, wo[s])`` per texel and channel, ``(T, C)``, of the model-form ``params``, each
    texel from its own ``wi`` ``(T, 3)`` over the shared directions ``wo`` ``(S, 3)``, by the model's fit kernel
    (a quadrature, without the ``(T, S)`` arrays :func:`evaluate` would make); None where it has no kernel."""
    form = model.fit_form()
    kernel = getattr(form, "kernel", None)
    if kernel is None or not params:
        return None
    T = np.shape(next(iter(params.values())))[0]
    x = _c(form.pack(params if form is model else form.from_model(params)))
    wi, wo, weights = _c(np.broadcast_to(wi, (T, 3))), _c(wo), _c(weights)
    out = np.empty((T, getattr(form, "channels", 3)))
    mod, cfg = _compiled(form)
    over_texels(T, lambda a, b: mod.weighted_sums(cfg, x[a:b], wi[a:b], wo, weights, out[a:b]), T * len(wo))
    return out


def project(form, x, limits) -> np.ndarray | None:
    """Packed fit-form rows ``x`` ``(T, K)`` onto each texel's ``limits``: ``form.constrain``, compiled (what the
    starting points, LM's NumPy loop and the Fit node's bounds project with).  By the form's ``project_kernel``
    inside its box, or, for a form whose box and peak widening are the whole of it (``peak_widths``), the box
    and the compiled widening.  None where the form has neither, or no fit kernel."""
    if getattr(form, "kernel", None) is None:
        return None
    kernel = getattr(form, "project_kernel", None)
    widths = getattr(form, "peak_widths", None)
    widths = None if kernel is not None or widths is None else widths()
    if kernel is None and widths is None:
        return None
    T = x.shape[0]
    lo, hi = (_c(b) for b in _box(form, form.bounds(), limits, T))
    out = np.empty((T, x.shape[1]))
    x = _c(x)
    mod, cfg = _compiled(form)
    if kernel is not None:
        lim = _c(form.project_limits(limits, T))
        over_texels(T, lambda a, b: mod.project_rows(cfg, x[a:b], lim[a:b], lo[a:b], hi[a:b], out[a:b]),
                    T * x.shape[1])
        return out
    w, log_bound, mi, mo, cos2 = peak_bound(widths, limits, T)
    channels = getattr(form, "channels", 3)
    over_texels(T, lambda a, b: mod.widen_rows(cfg, x[a:b], lo[a:b], hi[a:b], w, log_bound[a:b], mi, mo, cos2,
                                               channels, out[a:b]), T * max(len(mi), 1) * 8)
    return out


def solve_linear(form, x, free, f_r, weight, wi, wo, with_cost: bool = False):
    """Packed fit-form rows ``x`` ``(T, K)`` (clipped to the form's bounds) with the ``free`` parameters
    (magnitudes: f_r is affine in them) solved by least squares weighted by ``weight`` ``(T, S)``, the others
    held, clipped to the bounds: what :meth:`~sbrdf_core.brdf.BRDFModel.refine_linear` computes, by the form's
    fit kernel.  ``with_cost``: ``(rows, objective Σ (weight (f − f_r))² at them)``, from the same pass."""
    T, K = x.shape
    lo, hi = (_c(b) for b in form.bounds())
    out, cost = np.empty((T, K)), np.empty(T)
    x, free = _c(x), _c(free, np.uint8)
    f_r, wi, wo, w = _c(f_r), _c(wi), _c(wo), _c(np.broadcast_to(weight, np.shape(f_r)[:2]))
    mod, cfg = _compiled(form)
    over_texels(T, lambda a, b: mod.linear_solve(cfg, x[a:b], free, lo, hi, f_r[a:b], w[a:b], wi[a:b], wo[a:b],
                                                 out[a:b], cost[a:b]), T * f_r.shape[1])
    return (out, cost) if with_cost else out


def compiled_problem(form, f_r, weight, wi, wo) -> CompiledProblem | None:
    """The compiled problem of ``form`` where it has a fit kernel, else None (the NumPy problem applies)."""
    return None if getattr(form, "kernel", None) is None else CompiledProblem(form, f_r, weight, wi, wo)
