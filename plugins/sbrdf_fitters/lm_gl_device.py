"""lm-gl's GPU side: one EGL context on one thread, and texel tiles streamed through double-buffered SSBOs.

An EGL context is current in one thread at a time, while the Fit node calls
fitters from dask's worker threads; so every GL call runs on a single
``lm-gl`` thread that owns a standalone context (created as
:func:`sbrdf_lib.gl.context` creates the renderer's, but asking for GL 4.3),
and ``fit`` calls from any thread queue there.

Streaming: tile k+1 is packed and uploaded into the other buffer pair while
tile k computes; the read-back of tile k then waits only for its own
dispatch.  On a discrete GPU the upload overlaps compute; on llvmpipe the
"GPU" is the same cores, so there is little to overlap.
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from sbrdf_core.constraints_glsl import LIMITS_STRIDE
from sbrdf_core.errors import SbrdfError

from . import lm_gl_shader

logger = logging.getLogger(__name__)

_EXECUTOR = ThreadPoolExecutor(max_workers=1, thread_name_prefix="lm-gl")
_LOCAL = threading.local()  # the context and compiled programs, on the lm-gl thread only


def call(fn, *args, **kw):
    """Run ``fn(ctx, *args, **kw)`` on the lm-gl thread and return its result."""
    return _EXECUTOR.submit(lambda: fn(_context(), *args, **kw)).result()


def _context():
    ctx = getattr(_LOCAL, "ctx", None)
    if ctx is None:
        from sbrdf_core.extras import require

        moderngl = require("moderngl", feature="the lm-gl fitter")
        try:
            ctx = moderngl.create_context(standalone=True, backend="egl", require=430)
        except Exception as e:  # no libEGL, no driver, or no GL 4.3
            raise SbrdfError(f"lm-gl: cannot create an OpenGL 4.3 context (compute shaders) through EGL ({e}); "
                             "install Mesa's EGL (Debian: libegl1 libgl1-mesa-dri) or use the lm fitter") from None
        _LOCAL.ctx, _LOCAL.programs = ctx, {}
        logger.info("lm-gl context: %s", ctx.info.get("GL_RENDERER"))
    return ctx


def device_name() -> str:
    return call(lambda ctx: str(ctx.info.get("GL_RENDERER", "unknown")))


def _program(ctx, src: str):
    prog = _LOCAL.programs.get(src)
    if prog is None:
        try:
            prog = ctx.compute_shader(src)
        except Exception as e:
            raise SbrdfError(f"lm-gl: the model's GLSL fit gradient does not compile: {e}") from None
        _LOCAL.programs[src] = prog
    return prog


def _uniforms(prog, **values) -> None:
    for name, value in values.items():
        if name not in prog:
            continue
        if isinstance(value, np.ndarray):
            prog[name].write(np.asarray(value, "f4").tobytes())
        else:
            prog[name].value = value


def _pack(f_r, weight, wi, wo, x0, status, exact, sl):
    """Samples ``[S][n][10]`` (neighbouring invocations read nearby words) and state ``[n][K + 4]`` of texels ``sl``."""
    S, K = f_r.shape[1], x0.shape[1]
    n = len(range(*sl.indices(f_r.shape[0]))) if isinstance(sl, slice) else len(sl)
    data = np.empty((S, n, lm_gl_shader.SAMPLE), np.float32)
    data[..., 0:3] = wi[sl].transpose(1, 0, 2)
    data[..., 3:6] = wo[sl].transpose(1, 0, 2)
    data[..., 6:9] = f_r[sl].transpose(1, 0, 2)
    data[..., 9] = weight[sl].T
    state = np.zeros((n, lm_gl_shader.state_stride(K)), np.float32)
    state[:, :K], state[:, K + 1], state[:, K + 2] = x0[sl], status[sl], exact[sl]
    return data, state


def _max_step(max_step, K: int) -> np.ndarray:
    """The ``u_max_step`` uniform: float32, the largest finite float32 for "unbounded"."""
    m = np.full(K, np.inf) if max_step is None else np.asarray(max_step, np.float64)
    return np.minimum(m, np.finfo(np.float32).max).astype(np.float32)


def _result(out, K):
    x = out[:, :K].astype(np.float64)
    status = out[:, K + 1]
    return x, out[:, K].astype(np.float64), (status > 0.5) & (status < 1.5), out[:, K + 3].astype(np.int64)


def run_tiles(ctx, src: str, x0, status, exact, f_r, weight, wi, wo, *, lo, hi, free, iterations: int,
              tolerance: float, damping: float, tile: int, timings: dict, limits=None, max_step=None):
    """LM from ``x0 (T, K)`` on every texel, ``tile`` texels per dispatch; ``(x, cost, converged, iterations)``.

    ``weight (T, S)`` already includes the residual scale; ``status`` 1 marks
    texels to leave at ``x0``; ``exact`` is each texel's exact-fit cost.
    ``limits``, ``(packed (T, 3), growth, max_theta)`` as
    :mod:`sbrdf_core.constraints_glsl` packs them, has the shader project the
    start and every trial point (``src`` built with the model's
    ``glsl_fit_constrain``).  ``max_step`` ``(K,)``: the longest step per
    parameter (the form's ``max_step``; None: unbounded).
    """
    T, K = x0.shape
    S = f_r.shape[1]
    prog = _program(ctx, src)
    growth, max_theta = (-1.0, 0.0) if limits is None else limits[1:]
    chunk = lm_gl_shader.chunk(S, K, limits is not None)
    _uniforms(prog, u_lo=lo, u_hi=hi, u_free=free.astype(np.float32), u_max_step=_max_step(max_step, K),
              u_samples=S, u_iterations=int(iterations),
              u_tolerance=float(tolerance), u_damping=float(damping), u_constrain=int(limits is not None),
              u_growth=float(growth), u_max_theta=float(max_theta), u_chunk=chunk)
    stride = lm_gl_shader.state_stride(K)
    size = min(tile, T)
    pairs = [(ctx.buffer(reserve=max(S, 1) * size * lm_gl_shader.SAMPLE * 4), ctx.buffer(reserve=size * stride * 4),
              ctx.buffer(reserve=size * LIMITS_STRIDE * 4), ctx.buffer(reserve=size * lm_gl_shader.work_stride(K) * 4))
             for _ in range(2 if T > size else 1)]
    out = np.zeros((T, stride), np.float32)
    pending = None
    try:
        for k, start in enumerate(range(0, T, size)):
            t0 = time.perf_counter()
            sl = slice(start, min(start + size, T))
            data, state = _pack(f_r, weight, wi, wo, x0, status, exact, sl)
            samples_buf, state_buf, limits_buf, work_buf = pairs[k % len(pairs)]
            samples_buf.write(data.tobytes())
            state_buf.write(state.tobytes())
            if limits is not None:
                limits_buf.write(np.ascontiguousarray(limits[0][sl], np.float32).tobytes())
            t1 = time.perf_counter()
            samples_buf.bind_to_storage_buffer(0)
            state_buf.bind_to_storage_buffer(1)
            work_buf.bind_to_storage_buffer(2)
            limits_buf.bind_to_storage_buffer(3)
            prog["u_texels"].value = state.shape[0]
            groups = (state.shape[0] + lm_gl_shader.GROUP - 1) // lm_gl_shader.GROUP
            for mode in [1] + [0] * -(-int(iterations) // chunk):  # the start, then the iterations in chunks
                prog["u_mode"].value = mode
                prog.run(groups)
                ctx.memory_barrier()
            t2 = time.perf_counter()
            timings["upload_s"] = timings.get("upload_s", 0.0) + t1 - t0
            timings["compute_s"] = timings.get("compute_s", 0.0) + t2 - t1
            if pending is not None:
                _read(pending, out, timings)
            pending = (state_buf, sl, stride)
        if pending is not None:
            _read(pending, out, timings)
    finally:
        for buffers in pairs:
            for b in buffers:
                b.release()
    return _result(out, K)


def run_stepwise(ctx, src: str, x0, status, exact, f_r, weight, wi, wo, *, lo, hi, free, iterations: int,
                 tolerance: float, damping: float, project, timings: dict, max_step=None):
    """LM from ``x0`` with every trial point projected by ``project(x, idx)`` on the CPU (two dispatches and a
    round trip per iteration; all texels at once): ``lm``'s fit inside the limits, for the texels that need it."""
    T, K = x0.shape
    S = f_r.shape[1]
    prog = _program(ctx, src)
    _uniforms(prog, u_lo=lo, u_hi=hi, u_free=free.astype(np.float32), u_max_step=_max_step(max_step, K),
              u_samples=S, u_iterations=int(iterations),
              u_tolerance=float(tolerance), u_damping=float(damping), u_texels=T, u_constrain=0)
    stride, work_stride = lm_gl_shader.state_stride(K), lm_gl_shader.work_stride(K)
    NA = K * (K + 1) // 2
    t0 = time.perf_counter()
    data, state = _pack(f_r, weight, wi, wo, x0, status, exact, slice(0, T))
    samples_buf, state_buf = ctx.buffer(data.tobytes()), ctx.buffer(state.tobytes())
    work_buf = ctx.buffer(reserve=T * work_stride * 4)
    unused = ctx.buffer(reserve=16)  # the limits binding, not read: the CPU projects
    timings["upload_s"] = timings.get("upload_s", 0.0) + time.perf_counter() - t0
    groups = (T + lm_gl_shader.GROUP - 1) // lm_gl_shader.GROUP
    trial = slice(NA + K, NA + 2 * K)
    try:
        t0 = time.perf_counter()
        samples_buf.bind_to_storage_buffer(0)
        state_buf.bind_to_storage_buffer(1)
        work_buf.bind_to_storage_buffer(2)
        unused.bind_to_storage_buffer(3)
        prog["u_mode"].value = 1
        prog.run(groups)
        ctx.memory_barrier()
        for _ in range(iterations):
            prog["u_mode"].value = 2
            prog.run(groups)
            ctx.memory_barrier()
            work = np.frombuffer(work_buf.read(), np.float32).reshape(T, work_stride).copy()
            running = np.flatnonzero(np.frombuffer(state_buf.read(), np.float32).reshape(T, stride)[:, K + 1] == 0)
            if running.size == 0:
                break
            work[running, trial] = project(work[running, trial].astype(np.float64), running)
            work_buf.write(work.tobytes())
            prog["u_mode"].value = 3
            prog.run(groups)
            ctx.memory_barrier()
        out = np.frombuffer(state_buf.read(), np.float32).reshape(T, stride).copy()
        timings["compute_s"] = timings.get("compute_s", 0.0) + time.perf_counter() - t0
    finally:
        for b in (samples_buf, state_buf, work_buf, unused):
            b.release()
    return _result(out, K)


def _read(pending, out, timings) -> None:
    buf, sl, stride = pending
    t0 = time.perf_counter()
    out[sl] = np.frombuffer(buf.read(size=(sl.stop - sl.start) * stride * 4), np.float32).reshape(-1, stride)
    timings["compute_s"] = timings.get("compute_s", 0.0) + time.perf_counter() - t0
