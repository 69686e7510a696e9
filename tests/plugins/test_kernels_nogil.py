"""The Lafortune kernels release the GIL, so the Fit node's dask threads run their tiles' kernels side by side."""

from __future__ import annotations

import numba
import numpy as np

from sbrdf_models import lafortune_kernels


def _dispatchers():
    return {name: obj for name, obj in vars(lafortune_kernels).items()
            if isinstance(obj, numba.core.registry.CPUDispatcher)}


def test_every_kernel_callable_from_python_releases_the_gil():
    kernels = _dispatchers()
    entry = {name for name, d in kernels.items() if d.targetoptions.get("inline", "never") != "always"}
    assert {"lm_isotropic", "prepare_isotropic", "scan_first_exponent", "lobe_quadrature"} <= entry
    held = sorted(name for name in entry if not kernels[name].targetoptions.get("nogil"))
    assert held == []


def test_lobe_quadrature_through_run_parallel_from_threads():
    """Concurrent calls of a parallel kernel (two dask threads) give each caller its own, correct sums."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(0)
    a = rng.normal(size=(64, 1, 3))
    n = rng.uniform(1, 50, (64, 1))
    dirs = rng.normal(size=(200, 3))
    dirs[:, 2] = np.abs(dirs[:, 2])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    w = np.full(200, 2 * np.pi / 200)
    ref = lafortune_kernels.run_parallel(lafortune_kernels.lobe_quadrature, a, n, dirs, w)
    with ThreadPoolExecutor(2) as pool:
        outs = list(pool.map(lambda _: lafortune_kernels.run_parallel(lafortune_kernels.lobe_quadrature,
                                                                      a, n, dirs, w), range(8)))
    assert all(o.tobytes() == ref.tobytes() for o in outs)
