"""What a plugin module imports: the ``hookimpl`` marker and :class:`PluginSpec`.

A plugin contributes by returning light :class:`PluginSpec` descriptors from
its hooks (see :mod:`sbrdf_core.hookspecs`).  A descriptor names its
implementation by import path, so listing, validating and documenting plugins
imports no heavy code (OpenCV, OpenGL, device SDKs); the implementation is
imported the first time a graph actually uses it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pluggy

from .params import Param

#: Decorator for hook implementations: ``@hookimpl def sbrdf_fitters(): ...``
hookimpl = pluggy.HookimplMarker("sbrdf")

#: The contribution categories, each gathered by one ``sbrdf_<category>s`` hook.
CATEGORIES = {
    "capture": "sbrdf_captures",
    "device": "sbrdf_devices",
    "registration": "sbrdf_registrations",
    "fitter": "sbrdf_fitters",
    "quantizer": "sbrdf_quantizers",
    "renderer": "sbrdf_renderers",
    "brdf-model": "sbrdf_brdf_models",
    "scene-effect": "sbrdf_scene_effects",
    "parameterization": "sbrdf_parameterizations",
    "exporter": "sbrdf_exporters",
    "command": "sbrdf_commands",
}


@dataclass(frozen=True)
class PluginSpec:
    """A static description of one contribution.

    Parameters
    ----------
    name
        Registry name as written in YAML, lowercase-hyphenated (``lafortune-lm``).
    impl
        ``"package.module:Attribute"`` of the implementation class, imported on first use.
    params
        Declared parameters; the implementation is constructed as ``impl(**values)``.
        Leave it out (``None``) to use the implementation's own declaration,
        the class attribute ``params`` beside its ``__init__`` (the registry
        reads it when the spec is first used and checks that ``__init__``'s
        keyword arguments and defaults agree with it).
    summary
        One line for listings.
    doc
        Longer text for the reference docs (defaults to the implementation's docstring).
    """

    name: str
    impl: str
    params: tuple[Param, ...] | None = None
    summary: str = ""
    doc: str = ""
    # Filled in by the registry, not by plugin authors:
    category: str = ""
    plugin: str = field(default="", compare=False)
    distribution: str = field(default="", compare=False)
    version: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not self.name or self.name != self.name.lower() or " " in self.name or "_" in self.name:
            raise ValueError(f"plugin name {self.name!r} must be lowercase-hyphenated, e.g. 'lafortune-lm'")
        if ":" not in self.impl:
            raise ValueError(f"plugin {self.name!r}: impl {self.impl!r} must look like 'package.module:Class'")
        names = [p.name for p in self.params or ()]
        if len(names) != len(set(names)):
            raise ValueError(f"plugin {self.name!r} declares a parameter twice: {names}")
