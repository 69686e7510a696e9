"""Built-in renderers: ``preview`` (the flat sample), ``cpu`` (the reference) and ``gl`` (real time).

``cpu`` and ``gl`` draw a scene file (:mod:`sbrdf_lib.scene`, ``docs/scenes.md``)
and simulate only what it calls for.  Each renderer's parameters are
declared in :mod:`.declarations`, which imports no renderer.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_renderers():
    return [
        PluginSpec("preview", "sbrdf_render.preview:PreviewRenderer", params=declarations.PREVIEW,
                   summary="The flat sample under one point light, one pixel per texel (CPU, any model)"),
        PluginSpec("cpu", "sbrdf_render.cpu:CPURenderer", params=declarations.CPU,
                   summary="NumPy reference: ray-cast scene, any BRDF model, exact shadows"),
        PluginSpec("gl", "sbrdf_render.gl:GLRenderer", params=declarations.GL,
                   summary="moderngl/EGL real-time renderer, shaders generated from the scene and the models' GLSL"),
    ]


@hookimpl(optionalhook=True)
def sbrdf_reference_pages(registry):
    """The scene-file reference: the renderers' keys and those the installed plugins add (``sbrdf_scene_keys``)."""
    from sbrdf_lib.scene import reference

    return {"reference/scene.md": reference(registry)}
