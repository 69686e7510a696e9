"""Plugin discovery and lookup by name.

Every plugin, built-in or third-party, is a module named by an entry point in
the ``sbrdf`` group.  Loading one registers it with pluggy, which checks its
hook implementations against :mod:`sbrdf_core.hookspecs`; a plugin that fails
to import becomes a warning naming its entry point and the rest still load.
Implementations are imported on first use (:meth:`Registry.load`).
"""

from __future__ import annotations

import importlib
import os
import threading
import warnings
from collections.abc import Iterable
from dataclasses import replace
from functools import lru_cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any

import pluggy

from . import hookspecs
from .errors import PluginError
from .params import resolve
from .plugin import CATEGORIES, PluginSpec

ENTRY_POINT_GROUP = "sbrdf"

#: Plugins that cannot be disabled: the node kinds themselves.
ESSENTIAL_PLUGINS = ("sbrdf_core.nodes",)

#: Comma-separated plugin names to skip, like ``sbrdf -p no:NAME``.
DISABLE_ENV = "SBRDF_DISABLE_PLUGINS"


class PluginLoadWarning(RuntimeWarning):
    """A plugin failed to import or register and was skipped."""


def import_path(path: str) -> Any:
    """Import ``"package.module:Attr"``."""
    module, _, attr = path.partition(":")
    obj = importlib.import_module(module)
    for part in attr.split(".") if attr else []:
        obj = getattr(obj, part)
    return obj


class Registry:
    """All installed contributions, by category and name.

    Parameters
    ----------
    disabled
        Plugin (entry-point) names to skip; :data:`ESSENTIAL_PLUGINS` cannot be.
    extra
        Module paths or objects to register in addition to entry points (the
        CLI's ``-p module``), e.g. a plugin under development.
    entry_points_
        Entry points to load instead of the installed ones (tests).
    """

    def __init__(
        self,
        disabled: Iterable[str] = (),
        extra: Iterable[Any] = (),
        entry_points_: Iterable[EntryPoint] | None = None,
    ):
        self.pm = pluggy.PluginManager("sbrdf")
        self.pm.add_hookspecs(hookspecs)
        self.disabled = set(disabled) | {n for n in os.environ.get(DISABLE_ENV, "").split(",") if n}
        self.failed: dict[str, str] = {}
        self._impls: dict[tuple[str, str], Any] = {}
        self._lock = threading.Lock()
        for name in ESSENTIAL_PLUGINS:
            self._register(importlib.import_module(name), name, dist=("sbrdf", _version("sbrdf")))
        eps = entry_points(group=ENTRY_POINT_GROUP) if entry_points_ is None else entry_points_
        for ep in eps:
            if ep.name in self.disabled:
                continue
            try:
                obj = ep.load()
            except Exception as e:  # a broken plugin must not break discovery
                self.failed[ep.name] = f"{type(e).__name__}: {e}"
                warnings.warn(f"sbrdf plugin {ep.name!r} ({ep.value}) failed to load: {e}", PluginLoadWarning, stacklevel=2)
                continue
            dist = (ep.dist.name, ep.dist.version) if ep.dist is not None else ("", "")
            self._register(obj, ep.name, dist)
        for obj in extra:
            if isinstance(obj, str):
                name, obj = obj, importlib.import_module(obj)
            else:
                name = getattr(obj, "__name__", repr(obj))
            self._register(obj, name, dist=("", getattr(obj, "__version__", "dev")))
        self.pm.check_pending()
        self.node_kinds = self._collect_node_kinds()
        self.specs = self._collect_specs()

    # -- loading ------------------------------------------------------------

    def _register(self, obj: Any, name: str, dist: tuple[str, str]) -> None:
        try:
            self.pm.register(obj, name=name)
        except ValueError as e:  # already registered under this name
            raise PluginError(f"plugin {name!r} is registered twice: {e}") from e
        except pluggy.PluginValidationError as e:
            raise PluginError(f"plugin {name!r} ({dist[0] or 'no distribution'}) is invalid: {e}") from e
        self._dists = getattr(self, "_dists", {})
        self._dists[name] = dist

    def _collect_node_kinds(self) -> dict[str, type]:
        kinds: dict[str, type] = {}
        for impl in self.pm.hook.sbrdf_node_kinds.get_hookimpls():
            for kind in impl.function() or ():
                if kind.name in kinds:
                    raise PluginError(f"node kind {kind.name!r} is defined by two plugins ({impl.plugin_name} and another)")
                kinds[kind.name] = kind
        return kinds

    def _collect_specs(self) -> dict[str, dict[str, PluginSpec]]:
        specs: dict[str, dict[str, PluginSpec]] = {c: {} for c in CATEGORIES}
        for category, hook_name in CATEGORIES.items():
            for impl in getattr(self.pm.hook, hook_name).get_hookimpls():
                dist, version = self._dists.get(impl.plugin_name, ("", ""))
                for spec in impl.function() or ():
                    if not isinstance(spec, PluginSpec):
                        raise PluginError(f"plugin {impl.plugin_name!r}: {hook_name} must return PluginSpec objects, got {spec!r}")
                    spec = replace(spec, category=category, plugin=impl.plugin_name, distribution=dist, version=version)
                    old = specs[category].get(spec.name)
                    if old is not None:
                        raise PluginError(
                            f"{category} {spec.name!r} is contributed twice: by plugin {old.plugin!r} "
                            f"({old.distribution or 'no distribution'}) and by {spec.plugin!r} ({dist or 'no distribution'})"
                        )
                    specs[category][spec.name] = spec
        return specs

    # -- lookup ---------------------------------------------------------------

    def names(self, category: str) -> list[str]:
        return sorted(self.specs[category])

    def get(self, category: str, name: str) -> PluginSpec:
        """The spec of ``name`` in ``category``; the error lists what is installed."""
        if category not in self.specs:
            raise PluginError(f"unknown plugin category {category!r}; known: {sorted(self.specs)}")
        try:
            return self.specs[category][name]
        except KeyError:
            known = ", ".join(self.names(category)) or "none installed"
            raise PluginError(f"unknown {category} plugin {name!r}; installed: {known}") from None

    def load(self, spec: PluginSpec) -> Any:
        """Import the implementation of ``spec`` (once)."""
        key = (spec.category, spec.name)
        with self._lock:
            if key not in self._impls:
                try:
                    self._impls[key] = import_path(spec.impl)
                except Exception as e:
                    raise PluginError(f"{spec.category} plugin {spec.name!r} ({spec.plugin}): cannot import {spec.impl}: {e}") from e
            return self._impls[key]

    def create(self, category: str, name: str, params: dict | None = None) -> Any:
        """Validate ``params`` against the declaration and construct the implementation."""
        spec = self.get(category, name)
        values, problems = resolve(spec.params, params, f"{category} {name!r}")
        if problems:
            raise PluginError("; ".join(msg for _, msg in problems))
        return self.load(spec)(**values)


def _version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        from . import __version__

        return __version__


@lru_cache(maxsize=1)
def default_registry() -> Registry:
    """The process-wide registry of installed plugins (cached)."""
    return Registry()
