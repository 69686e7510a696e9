"""The plugin author's contract: every hook sbrdf calls, in one module.

A plugin is a module (or object) with functions named after these hooks and
decorated with :data:`sbrdf_core.plugin.hookimpl`, registered through the
``sbrdf`` entry-point group of its distribution::

    [project.entry-points.sbrdf]
    my_models = "my_package.plugin"

The built-in plugins under ``plugins/`` come in through exactly the same door.

Most hooks are *registration hooks*: they take no arguments and return a list
of :class:`~sbrdf_core.plugin.PluginSpec` describing contributions of one
category.  The implementation named by ``PluginSpec.impl`` is imported only
when a graph uses it, and must follow its category's protocol in
:mod:`sbrdf_core.contracts` (the registry checks it on import; the optional
members and what happens without them are declared there too).  Its
parameters are declared on the implementation class beside ``__init__``
(``params = (Param(...), ...)``).

An implementation that needs other plugins (a capture source rendering with
a BRDF model, a rig driving devices, a renderer using a quantizer) defines
``bind(registry)`` and looks them up by name; plugins never import each
other (``tests/core/test_layering.py``).  Code they share lives in the
library layer :mod:`sbrdf_lib`.

Call semantics of every registration hook: *collected* (every plugin's list is
concatenated), called once per process when the registry loads.  A name
contributed twice in one category is an error naming both plugins.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:  # importing the contract never imports the engine
    from .artifacts import ArtifactKind
    from .nodes.base import NodeKind
    from .params import Param
    from .plugin import PluginSpec
    from .types import PluginRegistry

hookspec = pluggy.HookspecMarker("sbrdf")


# ---------------------------------------------------------------------------
# Framework
# ---------------------------------------------------------------------------


@hookspec
def sbrdf_node_kinds() -> list[type[NodeKind]]:
    """Node kinds that graphs may use (``kind:`` in YAML).

    :returns: :class:`~sbrdf_core.nodes.base.NodeKind` subclasses.

    The six kinds of the pipeline (Capture, Register, Reflectance, Fit,
    Quantize, Render) are registered by the essential plugin
    :mod:`sbrdf_core.nodes`, which cannot be disabled.

    Call semantics: collected; called once when the registry loads.
    """


@hookspec
def sbrdf_artifact_kinds() -> list[ArtifactKind]:
    """Artifact kinds a plugin's node kinds write (a shading map, a measured table).

    :returns: :class:`~sbrdf_core.artifacts.ArtifactKind` declarations; a kind
        whose ``material`` names an adapter is accepted by the ``Render`` node.

    Call semantics: collected; called once when the registry loads, which
    records the kinds so stores and ``sbrdf info`` know them.
    """


@hookspec
def sbrdf_scene_keys() -> dict[str, tuple[Param, ...]]:
    """Scene-file keys a plugin adds (an environment, a reflector flag, a shading-map material).

    :returns: scope -> declarations.  ``"scene"``: top-level sections, each a
        ``dict`` Param with ``schema=``; sub-keys with ``extra={"path": True}``
        resolve from the scene file and must exist; a section with
        ``extra={"light": True}`` counts as a light.  ``"material"``: keys of
        every material; a key with ``extra={"store": True}`` names a store
        (``input`` or a path) of a kind with ``ArtifactKind.material``, and the
        other keys of the same tuple are passed to that kind's adapter as
        options.  ``"object"``: keys of every object.  ``"object.<shape>"``:
        keys of one shape.  Validated by the renderers' loader
        (:mod:`sbrdf_lib.scene`); an unknown key is an error with its line.

    Call semantics: collected; called whenever a scene is loaded.
    """


@hookspec
def sbrdf_reference_pages(registry: PluginRegistry) -> dict[str, str]:
    """Generated reference pages a plugin contributes: ``{path under docs/: markdown}``.

    The scene-file reference comes from the renderers this way, so the core's
    documentation generator names no scene key.

    Call semantics: collected; called when the documentation is built
    (:func:`sbrdf_core.docgen.pages`), results merged.
    """


# ---------------------------------------------------------------------------
# Capture
# ---------------------------------------------------------------------------


@hookspec
def sbrdf_captures() -> list[PluginSpec]:
    """Capture sources: the ``plugin:`` of a ``Capture`` node.

    Contract: :class:`~sbrdf_core.contracts.CaptureSource`.

    :returns: specs whose ``impl`` is a class constructed with the declared
        parameters and providing

        - ``describe() -> sbrdf_core.types.CaptureDescription``:
          pose count, image size, per-pose light/camera metadata; no pixels.
        - ``read_pose(index) -> (image, valid)``: linear HDR image
          ``(H, W, 3) float32`` in relative radiance and a ``(H, W) bool``
          mask of usable pixels (not saturated, not under-exposed).
        - ``sequential`` (class attribute, default ``False``): ``True`` for
          sources that drive hardware and must take poses one at a time, in
          order, in this process.
        - ``fingerprint() -> str`` (optional): changes when the source's data
          changes (e.g. a capture folder's files), so cached results are redone.

    Call semantics: collected; called once when the registry loads.
    """


@hookspec
def sbrdf_devices() -> list[PluginSpec]:
    """Device drivers (motor controllers, cameras) that capture sources drive.

    Contract: :class:`~sbrdf_core.contracts.MotorController` or :class:`~sbrdf_core.contracts.Camera`.

    :returns: specs whose ``impl`` is a driver class; devices are looked up by
        capture sources through :meth:`sbrdf_core.registry.Registry.create`,
        never by graphs directly.

    Call semantics: collected; called once when the registry loads.
    """


# ---------------------------------------------------------------------------
# Register
# ---------------------------------------------------------------------------


@hookspec
def sbrdf_registrations() -> list[PluginSpec]:
    """Registration methods: the ``plugin:`` of a ``Register`` node.

    Contract: :class:`~sbrdf_core.contracts.Registration`.

    :returns: specs whose ``impl`` provides

        - ``register(capture) -> sbrdf_core.types.Registration``:
          given the opened ``CaptureSet`` artifact, the texel grid and per-pose
          geometry (homography, RMS in mm, recovered camera centre, rejected
          poses with reasons).  May read pixels (e.g. fiducials) eagerly: it
          measures geometry, not the stack.
        - ``resample(image, valid, pose, registration) -> (texels, texel_valid)``:
          one accepted pose resampled onto the ``(V, U)`` texel grid.  Pure
          NumPy; called inside dask tasks.

    Call semantics: collected; called once when the registry loads.
    """


# ---------------------------------------------------------------------------
# Fit
# ---------------------------------------------------------------------------


@hookspec
def sbrdf_brdf_models() -> list[PluginSpec]:
    """BRDF models: what fitters fit, quantizers store and renderers shade.

    Contract: :class:`~sbrdf_core.contracts.BRDFModel`.

    :returns: specs whose ``impl`` is a :class:`sbrdf_core.brdf.BRDFModel`
        subclass; ``params`` are its configuration (number of lobes,
        anisotropy), not its per-texel parameters, which the instance declares
        in ``parameters``.

    Call semantics: collected; called once when the registry loads.
    """


@hookspec
def sbrdf_fitters() -> list[PluginSpec]:
    """Fitters: the ``plugin:`` of a ``Fit`` node.

    Contract: :class:`~sbrdf_core.contracts.Fitter`.

    :returns: specs whose ``impl`` provides

        - ``model_name``, ``model_config`` (attributes): the BRDF model it
          fits; the Fit node creates it from the registry.
        - ``fit(model, f_r, valid, wi, wo, limits=None) -> FitResult``:
          per-texel parameters for a batch of T texels with S samples each:
          ``f_r (T, S, 3)`` in sr^-1, ``valid (T, S)`` (held-out samples are
          already removed), directions ``(T, S, 3)`` in the sample frame.
          ``limits`` (:class:`~sbrdf_core.types.Limits`, optional
          keyword) are the texels' physical bounds: a fitter that takes it
          should fit inside them (``model.fit_form().constrain`` projects a
          trial point); the node projects whatever a fitter returns onto
          them anyway.  Vectorised over texels; called inside dask tasks,
          one texel tile at a time.

    Call semantics: collected; called once when the registry loads.
    """


@hookspec
def sbrdf_parameterizations() -> list[PluginSpec]:
    """Changes of variables of a BRDF into two 2D factor domains (separable BRDFs).

    Contract: :class:`~sbrdf_core.contracts.Parameterization`.

    :returns: specs whose ``impl`` provides

        - ``coords(wi, wo) -> (x, y)``: texture coordinates ``(..., 2)`` in
          [0, 1]^2 of the first and second factor for directions ``(..., 3)``
          in the surface frame (+z the normal, +x the primary tangent).
        - ``directions(x, y) -> (wi, wo)``: the inverse, broadcasting ``x``
          against ``y``, used to sample a BRDF on the factor grid.
        - ``wrap``: per factor, per texture axis, whether the axis is periodic.
        - ``glsl() -> str``: ``void sep_coords(vec3 wi, vec3 wo, out vec2 x,
          out vec2 y)`` computing the same coordinates per pixel.

    Consulted by the separable-BRDF fitters and the ``separable`` model
    (``plugins/sbrdf_separable``), never by graphs directly.

    Call semantics: collected; called once when the registry loads.
    """


# ---------------------------------------------------------------------------
# Quantize
# ---------------------------------------------------------------------------


@hookspec
def sbrdf_quantizers() -> list[PluginSpec]:
    """Texture layouts: the ``plugin:`` of a ``Quantize`` node.

    Contract: :class:`~sbrdf_core.contracts.Quantizer`.

    :returns: specs whose ``impl`` provides ``encode(params, model)``
        returning an ``sbrdf_core.types.Encoded`` (lazy textures, scale, bias) and
        ``decode(textures, scale, bias, model)`` returning parameter maps,
        optionally ``write_files`` and ``bytes_per_texel``; see
        :mod:`sbrdf_core.nodes.quantize`.  ``decode`` must not depend on the
        plugin's parameters (a TextureSet is decoded by a default instance).

    Call semantics: collected; called once when the registry loads.
    """


# ---------------------------------------------------------------------------
# Render
# ---------------------------------------------------------------------------


@hookspec
def sbrdf_renderers() -> list[PluginSpec]:
    """Renderers: the ``plugin:`` of a ``Render`` node.

    Contract: :class:`~sbrdf_core.contracts.Renderer`.

    :returns: specs whose ``impl`` provides ``render(material) -> sbrdf_core.types.RenderResult``
        where ``material`` is a :class:`sbrdf_core.types.Material`
        (model + lazy parameter maps); see :mod:`sbrdf_core.nodes.render`.

    Call semantics: collected; called once when the registry loads.
    """


@hookspec
def sbrdf_scene_effects() -> list[PluginSpec]:
    """Scene effects (environment lighting, mirrors): radiance the ``cpu`` and ``gl`` renderers add to L.

    Contract: :class:`~sbrdf_core.contracts.SceneEffect`.

    :returns: specs whose ``impl`` is a class providing

        - ``wanted(scene) -> bool`` (static): whether the scene calls for the
          effect (``environment:`` present, a ``reflector: true`` object).  A
          renderer constructs and runs only wanted effects, so a scene pays
          for nothing it does not use and its shaders contain no code of
          effects it does not want.
        - ``options(scene) -> dict`` (static): the effect's parameter values
          taken from the scene file, validated against the spec's ``params``
          when the renderer constructs it (``impl(**values)``).
        - ``check(scene) -> list[str]`` (optional): cheap checks of what
          ``prepare`` will need (files exist and can be read, scene-level
          conditions), run on the constructed effect when a graph that
          renders the scene is validated, so a render does not fail after
          the nodes upstream of it computed.  Constructors must stay cheap
          (store and check options; load in ``prepare``): they run then too.
        - ``prepare(scene, materials, gl_context=None)``: load data and
          precompute (maps, buffers); ``materials`` are the scene's resolved
          materials by name; ``gl_context`` is given by the ``gl`` renderer,
          which lets the effect precompute on the GPU.
        - ``cpu_radiance(material, hits, view_dirs, pixels) -> (R, 3)``: the
          effect's radiance at ``R`` ray hits (``sbrdf_lib.surface.Hits``,
          world space) of one scene material seen along ``view_dirs``;
          ``pixels`` are the hits' image pixel indices (per-pixel sequences).
        - ``glsl(material, exprs) -> (declarations, statements)``: GLSL
          declared before ``main`` and statements run in ``main`` after the
          lights, with ``N``, ``T``, ``B`` (world frame), ``V``, ``wo``
          (surface frame), ``v_pos`` and the accumulated ``vec3 L`` in scope;
          ``exprs`` maps each model parameter to its GLSL expression.
        - ``gl_prepare(drawer)`` (the ``GLScene``: context, meshes, programs,
          textures), ``gl_uniforms(program, first_unit) -> units
          used``, ``gl_use(first_unit) -> units used`` (bind its textures before a draw),
          ``gl_frame(drawer)`` (before each frame: extra passes, per-frame
          uniforms), ``release()``.

    Effects are consulted in registry order; each adds to L independently.
    Shadows are built into the renderers (``shadows: true``), not an effect.

    Call semantics: collected; called once when the registry loads.
    """


# ---------------------------------------------------------------------------
# Export and commands
# ---------------------------------------------------------------------------


@hookspec
def sbrdf_exporters() -> list[PluginSpec]:
    """Exporters: the ``plugin:`` of an ``Export`` node (glTF, MaterialX, USD, Mitsuba, EXR texture sets).

    Contract: :class:`~sbrdf_core.contracts.Exporter`.

    :returns: specs whose ``impl`` converts a material's parameter maps lazily
        (``convert``) and writes the files beside the stored maps (``write``);
        see :mod:`sbrdf_core.nodes.export`.

    Call semantics: collected; called once when the registry loads.
    """


@hookspec
def sbrdf_commands() -> list[PluginSpec]:
    """Command-line subcommands: ``sbrdf <name> ...`` (the viewer's ``sbrdf view``).

    Contract: :class:`~sbrdf_core.contracts.Command`.

    :returns: specs whose ``impl`` declares its arguments (``add_arguments``)
        and runs (``run(args) -> exit status``); the spec's ``summary`` is the
        subcommand's help line.  A name the core already uses is refused.

    Call semantics: collected; called once when the registry loads.
    """
