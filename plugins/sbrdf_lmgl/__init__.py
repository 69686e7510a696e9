"""The ``lm-gl`` fitter: the batched Levenberg–Marquardt of ``lm`` in OpenGL 4.3 compute shaders.

It runs wherever moderngl reaches an EGL driver with compute shaders (NVIDIA
drivers, Mesa llvmpipe in CI), with nothing larger to install than the
renderer already needs.  The model's value and gradient in GLSL are its
``fit_kernel`` translated (:mod:`sbrdf_core.engine_glsl`); see :mod:`.fitter`.  Its
parameters are declared in :mod:`.declarations`, which imports neither
moderngl nor the solver.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from .declarations import LM_GL


@hookimpl
def sbrdf_fitters():
    return [
        PluginSpec("lm-gl", "sbrdf_lmgl.fitter:GLLevenbergMarquardtFitter", params=LM_GL,
                   summary="The lm fitter's batched Levenberg-Marquardt in OpenGL compute shaders (GL 4.3, EGL)"),
    ]
