"""Built-in fitters (generic batched LM on the CPU, the same LM in OpenGL compute shaders, McAllister's procedure,
his line search), the SampleModel node and the Select node (the model with the lowest held-out error).

Each fitter's parameters are declared in :mod:`.declarations`, which imports no fitter (nor moderngl); the shared
solver is :mod:`sbrdf_lib.lm`.  ``lm-gl`` (:mod:`.lm_gl`) runs ``lm``'s iterations on the GPU wherever moderngl
reaches an EGL driver with compute shaders (NVIDIA drivers, Mesa llvmpipe in CI): its GLSL model value and
gradient are the model's ``fit_kernel`` translated (:mod:`sbrdf_core.engine_glsl`), its context and buffers are
in :mod:`.lm_gl_device`, its shader in :mod:`.lm_gl_shader`.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_node_kinds():
    from .sample_model import SampleModel
    from .select import Select

    return [SampleModel, Select]


@hookimpl
def sbrdf_fitters():
    return [
        PluginSpec("lm", "sbrdf_fitters.lm:LevenbergMarquardtFitter", params=declarations.LM,
                   summary="Batched Levenberg-Marquardt fit of any BRDF model, vectorised over texels"),
        PluginSpec("lm-gl", "sbrdf_fitters.lm_gl:GLLevenbergMarquardtFitter", params=declarations.LM_GL,
                   summary="The lm fitter's batched Levenberg-Marquardt in OpenGL compute shaders (GL 4.3, EGL)"),
        PluginSpec("mcallister", "sbrdf_fitters.mcallister:McAllisterFitter", params=declarations.MCALLISTER,
                   summary="McAllister's procedure: percentile rho_d, lobes fitted to luminance, rho_s by Eq 4.10"),
        PluginSpec("line-search", "sbrdf_fitters.mcallister:LineSearchFitter", params=declarations.LINE_SEARCH,
                   summary="McAllister's fast single-lobe fit: Brent search over n, least squares for C"),
    ]
