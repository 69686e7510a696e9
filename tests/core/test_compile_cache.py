"""numba's on-disk cache is reused across processes: a second process loads the kernels, compiles nothing and
adds no cache entry (every process and dask worker would pay the compilation again otherwise)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

#: Calls tile_directions' compiled pass and prints its dispatcher's cache hits and misses.
CALL = """
import numba, numpy as np
from sbrdf_core.geometry import _compiled_directions
k = _compiled_directions()
k(np.zeros((4, 3)), np.array([[0.0, 0.0, 100.0]]), np.array([[10.0, 0.0, 100.0]]))
print(sum(k.stats.cache_hits.values()), sum(k.stats.cache_misses.values()))
"""


def _entries(cache_dir) -> set[str]:
    """The cache's index (.nbi) and data (.nbc) files: one data file per compiled entry."""
    return {str(p.relative_to(cache_dir)) for p in cache_dir.rglob("*") if p.suffix in (".nbi", ".nbc")}


def test_a_second_process_loads_the_geometry_kernel_from_the_cache(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "NUMBA_DISABLE_JIT": "0"}

    def run() -> tuple[int, int]:
        out = subprocess.run([sys.executable, "-c", CALL], env=env, capture_output=True, text=True, check=True)
        hits, misses = out.stdout.split()[-2:]
        return int(hits), int(misses)

    assert run() == (0, 1)  # compiled and stored
    first = _entries(tmp_path)
    assert any(name.endswith(".nbc") for name in first), first
    assert run() == (1, 0)  # loaded, not compiled
    assert _entries(tmp_path) == first


@pytest.mark.parametrize("factory", [
    "sbrdf_core.geometry:_compiled_directions",
    "sbrdf_core.constraints:_compiled_negated_cosines",
    "sbrdf_core.channels:_compiled_abs_channel_mean",
    "sbrdf_core.nodes.fit:_compiled_usable",
    "sbrdf_core.nodes.reflectance:_fused",
    "sbrdf_register.aruco:_grid_kernel",
])
def test_cached_kernels_capture_no_closure_variable(factory):
    """numba keys a closure's cache entry by its pickled cells, which differ per process for a dispatcher:
    a cached kernel with cells would be compiled again, with a new entry, in every process."""
    import importlib

    module, name = factory.split(":")
    kernel = getattr(importlib.import_module(module), name)()
    assert kernel._cache is not None and type(kernel._cache).__name__ == "FunctionCache"
    assert kernel.py_func.__closure__ is None
