"""The fit-kernel translator (sbrdf_core.engine_glsl) on kernels of its own: what it refuses, and how it types.

The built-in kernels' translations are checked against NumPy by the conformance suite
(``BRDFModelTests.test_glsl_fit_gradient_matches_numpy``); these are the cases no model exercises.
"""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

from sbrdf_core.engine_glsl import KernelSubsetError, fit_gradient_glsl, kernel_glsl
from sbrdf_core.testing import glsl_fit_gradient_eval

SCALE = 0.5


def division_kernel(x, cfg, wi, wo, f, J):
    n = int(cfg[0])
    for c in range(3):
        f[c] = c / n + x[0] ** 2 * SCALE  # int / int: float division; ** 2 of a negative number
        for k in range(x.size):
            J[c, k] = 2.0 * SCALE * x[0] if k == 0 else 0.0
    if cfg[1] != 0.0:  # off in this configuration: its index past K is never written
        f[0] = x[7]


def while_kernel(x, cfg, wi, wo, f, J):
    k = 0
    while k < 3:
        f[k] = x[0]
        k += 1


def numpy_kernel(x, cfg, wi, wo, f, J):
    f[0] = np.exp(x[0])


class Tiny:
    """A one-parameter model that is its own fit form, around ``kernel``."""

    name = "tiny"
    size = 1

    def __init__(self, kernel, cfg):
        self.kernel, self.cfg = kernel, cfg

    def fit_form(self):
        return self

    def kernel_config(self):
        return np.array(self.cfg, np.float64)


def test_int_division_is_float_and_the_configuration_is_folded():
    src = fit_gradient_glsl(Tiny(division_kernel, (2.0, 0.0)))
    assert "float(c) / 2.0" in src  # n = int(cfg[0]) is the number 2; c a loop counter, int
    assert "sbrdf_powi(x[0], 2)" in src  # a product: pow() is undefined below 0
    assert "x[7]" not in src  # the branch cfg[1] != 0 is gone


def test_the_gpu_and_the_cpu_run_the_same_kernel():
    moderngl = pytest.importorskip("moderngl")
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl", require=430)
    except Exception as e:
        pytest.skip(f"no EGL context with compute shaders: {e}")
    x = np.array([-3.0])
    wi = wo = np.array([[0.0, 0.0, 1.0]])
    try:
        got_f, got_J = glsl_fit_gradient_eval(ctx, Tiny(division_kernel, (2.0, 0.0)), x, wi, wo)
    finally:
        ctx.release()
    f, J = np.zeros(3), np.zeros((3, 1))
    division_kernel(x, np.array([2.0, 0.0]), wi[0], wo[0], f, J)
    np.testing.assert_allclose(got_f[0], f, rtol=1e-6)  # 4.5, 5.0, 5.5
    np.testing.assert_allclose(got_J[0], J, rtol=1e-6)


@pytest.mark.parametrize("kernel, what, offset", [
    (while_kernel, "the statement While", 2),
    (numpy_kernel, "the call 'np.exp(x[0])'", 1),
])
def test_an_unsupported_construct_is_named_with_its_line(kernel, what, offset):
    line = inspect.getsourcelines(kernel)[1] + offset
    with pytest.raises(KernelSubsetError) as e:
        fit_gradient_glsl(Tiny(kernel, ()))
    msg = str(e.value)
    assert msg.startswith(f"tiny: fit kernel {__name__}.{kernel.__name__}, line {line}: {what}"), msg


def test_an_index_past_k_where_the_configuration_reaches_it_is_refused():
    with pytest.raises(KernelSubsetError, match=r"the index 7 = 7 out of 0\.\.0"):
        kernel_glsl(division_kernel, (2.0, 1.0), 1, 3, "tiny")


def test_float32_keeps_a_positive_floor():
    def floor_kernel(x, cfg, wi, wo, f, J):
        f[0] = max(x[0], 1e-300) + math.pi

    src = kernel_glsl(floor_kernel, (), 1, 3, "tiny")
    assert "max(x[0], 1.1754943508222875e-38) + 3.141592653589793" in src
