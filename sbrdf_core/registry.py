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

from . import contracts, hookspecs
from .artifacts import register_kind
from .errors import PluginError
from .params import REQUIRED, Param, resolve
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
            if self.pm.is_registered(obj):  # asked for explicitly and also installed: one registration
                continue
            self._register(obj, name, dist=("", getattr(obj, "__version__", "dev")))
        self.pm.check_pending()
        self.node_kinds = self._collect_node_kinds()
        self.specs = self._collect_specs()
        self.artifact_kinds = self._collect_artifact_kinds()

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
            kinds_of: Any = impl.function()  # pluggy types hook functions as object
            for kind in kinds_of or ():
                if kind.name in kinds:
                    raise PluginError(f"node kind {kind.name!r} is defined by two plugins ({impl.plugin_name} and another)")
                kinds[kind.name] = kind
        return kinds

    def _collect_artifact_kinds(self) -> dict[str, str]:
        """Record plugins' artifact kinds (``sbrdf_artifact_kinds``); returns kind -> plugin."""
        owners: dict[str, str] = {}
        for impl in self.pm.hook.sbrdf_artifact_kinds.get_hookimpls():
            declared: Any = impl.function()
            for kind in declared or ():
                if kind.kind in owners:
                    raise PluginError(f"artifact kind {kind.kind!r} is declared by plugins {owners[kind.kind]!r} "
                                      f"and {impl.plugin_name!r}")
                register_kind(kind, impl.plugin_name)
                owners[kind.kind] = impl.plugin_name
        return owners

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
            spec = self.specs[category][name]
        except KeyError:
            known = ", ".join(self.names(category)) or "none installed"
            raise PluginError(f"unknown {category} plugin {name!r}; installed: {known}") from None
        if spec.params is None:  # declared on the implementation class: import it once, keep the result
            spec = replace(spec, params=declared_params(self.load(spec), spec))
            self.specs[category][name] = spec
        return spec

    def load(self, spec: PluginSpec) -> Any:
        """Import the implementation of ``spec`` (once) and check it against its protocol.

        A missing optional dependency becomes a message naming the extra to
        install; an implementation lacking a member its category's protocol
        (:mod:`sbrdf_core.contracts`) requires is refused, naming the members.
        """
        key = (spec.category, spec.name)
        with self._lock:
            if key not in self._impls:
                try:
                    impl = import_path(spec.impl)
                except ModuleNotFoundError as e:
                    hint = _extra_hint(e.name)
                    raise PluginError(f"{spec.category} plugin {spec.name!r} ({spec.plugin}): cannot import "
                                      f"{spec.impl}: {e}{hint}") from e
                except Exception as e:
                    raise PluginError(f"{spec.category} plugin {spec.name!r} ({spec.plugin}): cannot import {spec.impl}: {e}") from e
                lacking = contracts.missing(spec.category, impl)
                if lacking:
                    raise PluginError(
                        f"{spec.category} plugin {spec.name!r} ({spec.plugin}): {spec.impl} does not implement "
                        f"{_protocol_names(spec.category)}: missing {', '.join(lacking)} (see sbrdf_core.contracts)")
                self._impls[key] = impl
            return self._impls[key]

    def create(self, category: str, name: str, params: dict | None = None) -> Any:
        """Validate ``params`` against the declaration and construct the implementation."""
        spec = self.get(category, name)
        values, problems = resolve(spec.params or (), params, f"{category} {name!r}")
        if problems:
            raise PluginError("; ".join(msg for _, msg in problems))
        return self.load(spec)(**values)


def _protocol_names(category: str) -> str:
    p = contracts.PROTOCOLS[category]
    return " or ".join(x.__name__ for x in (p if isinstance(p, tuple) else (p,)))


def _extra_hint(module: str | None) -> str:
    from .extras import EXTRAS

    extra = EXTRAS.get((module or "").split(".")[0])
    return f"; install it with: pip install 'sbrdf[{extra[0]}]'" if extra else ""


def declared_params(impl: Any, spec: PluginSpec | None = None) -> tuple[Param, ...]:
    """The parameters an implementation class declares beside its ``__init__`` (``params``)."""
    params = getattr(impl, "params", None)
    where = f"{spec.category} plugin {spec.name!r} ({spec.impl})" if spec else repr(impl)
    if params is None:
        return ()
    if callable(params) or not all(isinstance(p, Param) for p in params):
        raise PluginError(f"{where}: 'params' must be a tuple of sbrdf_core.params.Param")
    return tuple(params)


def signature_problems(impl: Any, params: tuple[Param, ...]) -> list[str]:
    """Where ``impl(**values)``'s signature disagrees with the declaration (names, defaults)."""
    import inspect

    try:
        sig = inspect.signature(impl)
    except (TypeError, ValueError):
        return []
    accepted = {n: p for n, p in sig.parameters.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    var_kw = any(p.kind is p.VAR_KEYWORD for p in sig.parameters.values())
    problems = []
    for p in params:
        arg = accepted.get(p.name)
        if arg is None:
            if not var_kw:
                problems.append(f"declared parameter {p.name!r} is not an argument of {impl.__name__}()")
            continue
        has_default = arg.default is not inspect.Parameter.empty
        if p.default is REQUIRED and has_default:
            problems.append(f"{p.name!r} is declared required but defaults to {arg.default!r} in the signature")
        elif p.default is not REQUIRED and not has_default:
            problems.append(f"{p.name!r} is declared with default {p.default!r} but the signature requires it")
        elif has_default and p.default is not REQUIRED and not _same(arg.default, p.default):
            problems.append(f"{p.name!r}: declared default {p.default!r} != signature default {arg.default!r}")
    declared = {p.name for p in params}
    for name, arg in accepted.items():
        if name not in declared and arg.default is inspect.Parameter.empty:
            problems.append(f"argument {name!r} of {impl.__name__}() is required but not declared")
    return problems


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return list(a) == list(b)
    return a == b


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
