"""YAML -> validated graph.  Everything is checked before anything runs.

A graph file::

    name: demo
    store: ../runs/demo            # local path (relative to this file) or fsspec URL
    nodes:
      capture: {kind: Capture, plugin: synthetic, params: {texels: [64, 64]}}
      register: {kind: Register, plugin: texel-aligned, in: {capture: capture}}

Every problem is collected and reported together, each with file and line:
syntax errors, unknown top-level or node keys, duplicate names, node names
that are not identifiers (:data:`sbrdf_core.store.NODE_NAME`), unknown node
kinds or plugins (listing the known ones), unknown, missing or ill-typed
parameters (listing the accepted ones with types and defaults), missing,
unknown or mistyped inputs, cycles, and stores that cannot be opened.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import yaml

from . import _yaml
from .contracts import optional
from .errors import GraphError, Problem
from .params import Param, resolve
from .registry import Registry, default_registry
from .store import NODE_NAME

if TYPE_CHECKING:
    from .nodes.base import NodeKind

TOP_KEYS = ("name", "store", "nodes", "description", "limits")
NODE_KEYS = ("kind", "plugin", "in", "params", "doc")


@dataclass
class Node:
    """One validated node: its kind class, plugin name, inputs and resolved parameters."""

    name: str
    kind: type[NodeKind]
    plugin: str | None
    inputs: dict[str, str]
    params: dict[str, Any]
    line: int | None = None


@dataclass
class Graph:
    """A validated graph; ``nodes`` are in an order where inputs come first."""

    name: str
    store: str
    nodes: dict[str, Node]
    file: str = "<graph>"
    digest: str = ""
    description: str = ""
    text: str = field(default="", repr=False)

    def url(self, node: str) -> str:
        """Where ``node``'s artifact lives."""
        return self.store.rstrip("/") + "/" + node


def load_graph(source: str | os.PathLike, registry: Registry | None = None, store: str | None = None) -> Graph:
    """Load and validate a graph from a file path (or YAML text containing a newline).

    Raises :class:`~sbrdf_core.errors.GraphError` listing every problem.
    """
    registry = registry or default_registry()
    src = str(source)
    if "\n" in src:
        text, file, base = src, "<graph>", Path.cwd()
    else:
        path = Path(src)
        try:
            text = _yaml.read_text(path)  # UTF-8 (or UTF-16/32 with a BOM); a binary or Latin-1 file is a file:line error
        except OSError as e:
            raise GraphError([Problem(f"cannot read graph file: {e.strerror}", str(path))]) from None
        except yaml.YAMLError as e:
            raise GraphError([_yaml.syntax_problem(e, str(path))]) from None
        file, base = str(path), path.resolve().parent
    return _Validator(text, file, base, registry, store).run()


class _Validator:
    def __init__(self, text: str, file: str, base: Path, registry: Registry, store: str | None):
        self.text, self.file, self.base, self.reg, self.store_override = text, file, base, registry, store
        self.problems: list[Problem] = []

    def problem(self, message: str, path: tuple = (), line: int | None = None) -> None:
        self.problems.append(Problem(message, self.file, line if line is not None else self.loc.line(path)))

    def run(self) -> Graph:
        try:
            doc, self.loc = _yaml.load(self.text)
        except yaml.YAMLError as e:
            raise GraphError([_yaml.syntax_problem(e, self.file)]) from None
        for path, line in self.loc.duplicates:
            what = "node" if len(path) == 2 and path[0] == "nodes" else "key"
            self.problem(f"duplicate {what} {path[-1]!r} (first defined on line {self.loc.lines.get(path)})", line=line)
        if not isinstance(doc, dict):
            self.problem("a graph must be a mapping with 'name', 'store' and 'nodes'", line=1)
            raise GraphError(self.problems)
        for key in doc:
            if key not in TOP_KEYS:
                self.problem(f"unknown top-level key {key!r}; allowed: {', '.join(TOP_KEYS)}", (key,))
        name = doc.get("name")
        if not isinstance(name, str) or not name:
            self.problem("graph needs a 'name' (a string)", ("name",))
        store = self._store(doc)
        raw_nodes = doc.get("nodes")
        if not isinstance(raw_nodes, dict) or not raw_nodes:
            self.problem("graph needs 'nodes': a mapping of node name -> {kind, plugin, in, params}", ("nodes",))
            raw_nodes = {}
        nodes = {}
        for nname, decl in raw_nodes.items():
            node = self._node(str(nname), decl)
            if node is not None:
                nodes[node.name] = node
        self._edges(nodes, raw_nodes)
        order = self._topological(nodes)
        self._estimate(doc.get("limits"), nodes, order, store)
        if self.problems:
            raise GraphError(sorted(self.problems, key=lambda p: (p.line or 0, p.message)))
        return Graph(
            name=cast(str, name),  # validated above
            store=store,
            nodes={n: nodes[n] for n in order},
            file=self.file,
            digest=hashlib.sha256(self.text.encode()).hexdigest(),
            description=str(doc.get("description", "")),
            text=self.text,
        )

    def _estimate(self, raw_limits: Any, nodes: dict[str, Node], order: list[str], store: str) -> None:
        """Each node's output bytes and peak memory against free disk and ``limits:`` (:mod:`.estimate`)."""
        from . import estimate

        limits, problems = estimate.limits_from(raw_limits)
        for key, msg in problems:
            self.problem(msg, ("limits", key) if key else ("limits",))
        if not self.problems and store:
            for name, msg in estimate.check(nodes, order, store, limits)[1]:
                self.problem(msg, ("nodes", name) if name else ("nodes",))

    # -- store ----------------------------------------------------------------

    def _store(self, doc: dict) -> str:
        raw = self.store_override if self.store_override is not None else doc.get("store")
        if not isinstance(raw, str) or not raw:
            self.problem("graph needs a 'store': a local path or fsspec URL where artifacts are written", ("store",))
            return ""
        import fsspec

        protocol = raw.split("://", 1)[0] if "://" in raw else "file"
        if protocol == "file":
            local = Path(raw.split("://", 1)[-1])
            local = local if local.is_absolute() else (self.base / local)
            url = str(local.resolve())
            probe = local
            while not probe.exists() and probe != probe.parent:
                probe = probe.parent
            if probe.exists() and not probe.is_dir():
                self.problem(f"store {raw!r} cannot be opened: {probe} is a file, not a directory", ("store",))
            elif not os.access(probe, os.W_OK | os.X_OK):
                self.problem(f"store {raw!r} cannot be opened: {probe} is not writable", ("store",))
            return url
        try:
            fs_cls = fsspec.get_filesystem_class(protocol)
        except (ValueError, ImportError) as e:
            self.problem(f"store {raw!r} cannot be opened: {e}", ("store",))
            return raw
        try:
            fs, root = fsspec.core.url_to_fs(raw)
            fs.exists(root)
        except Exception as e:  # credentials, network, bad bucket...
            self.problem(f"store {raw!r} cannot be opened ({fs_cls.__name__}): {e}", ("store",))
        return raw

    # -- nodes ----------------------------------------------------------------

    def _node(self, name: str, decl: Any) -> Node | None:
        path = ("nodes", name)
        if not NODE_NAME.fullmatch(name):  # it becomes <store>/<name>: no way out of the store
            self.problem(f"node name {name!r} is not an identifier (a letter or '_', then up to 63 letters, "
                         f"digits, '_' or '-')", path)
            return None
        if not isinstance(decl, dict):
            self.problem(f"node {name!r} must be a mapping with 'kind' (and 'plugin', 'in', 'params')", path)
            return None
        for key in decl:
            if key not in NODE_KEYS:
                self.problem(f"node {name!r}: unknown key {key!r}; allowed: {', '.join(NODE_KEYS)}", path + (key,))
        kind_name = decl.get("kind")
        kind = cast("type[NodeKind] | None", self.reg.node_kinds.get(kind_name) if isinstance(kind_name, str) else None)
        if kind is None:
            known = ", ".join(sorted(self.reg.node_kinds))
            what = f"unknown node kind {kind_name!r}" if kind_name is not None else "missing 'kind'"
            self.problem(f"node {name!r}: {what}; known kinds: {known}", path + ("kind",))
            return None
        declared: list[Param] = list(kind.params)
        plugin = decl.get("plugin", kind.default_plugin)
        spec = None
        if kind.plugin_category is None:
            if "plugin" in decl:
                self.problem(f"node {name!r}: {kind.name} nodes take no plugin", path + ("plugin",))
            plugin = None
        elif plugin is None:
            self.problem(
                f"node {name!r}: {kind.name} needs a 'plugin'; installed: {', '.join(self.reg.names(kind.plugin_category)) or 'none'}",
                path,
            )
        elif not isinstance(plugin, str) or plugin not in self.reg.specs[kind.plugin_category]:
            known = ", ".join(self.reg.names(kind.plugin_category)) or "none installed"
            self.problem(f"node {name!r}: unknown {kind.plugin_category} plugin {plugin!r}; installed: {known}", path + ("plugin",))
            plugin = None
        else:
            spec = self.reg.get(kind.plugin_category, plugin)
            declared += list(spec.params or ())  # filled in by Registry.get
        owner = f"{kind.name} plugin {plugin!r}" if spec else f"{kind.name} node"
        raw_params = decl.get("params", {}) or {}
        if not isinstance(raw_params, dict):
            self.problem(f"node {name!r}: 'params' must be a mapping", path + ("params",))
            raw_params = {}
        params = {}
        if kind.plugin_category is None or spec is not None:
            before = len(self.problems)
            params = self._params(declared, raw_params, owner, path + ("params",))
            if spec is not None and len(self.problems) == before:
                self._check_combination(spec, params, owner, path + ("params",))
            elif spec is None and len(self.problems) == before and callable(check := optional(kind, "check_params")):
                for key, msg in check(params):  # a node kind's own files (MeasuredTable's table)
                    self.problem(f"{owner}: {msg}", path + ("params", key) if key else path + ("params",))
        inputs = decl.get("in", {}) or {}
        if not isinstance(inputs, dict):
            self.problem(f"node {name!r}: 'in' must map input ports to node names", path + ("in",))
            inputs = {}
        return Node(name, kind, plugin, {str(k): v for k, v in inputs.items()}, params, self.loc.line(path))

    def _check_combination(self, spec, params: dict, owner: str, path: tuple) -> None:
        """Constraints between parameters that single declarations cannot express.

        A plugin implementation may define ``check_params(params) -> [(name or
        None, message)]``, a cheap check without side effects (devices are not
        opened), so the problem is reported with its line before anything runs;
        one with a ``registry`` keyword gets the validating registry.
        """
        try:
            impl = self.reg.load(spec)
        except Exception:  # the registry reports broken plugins itself
            return
        check = optional(impl, "check_params")
        if check is None:
            return
        try:  # a check that takes ``registry`` sees the plugins of this validation (``sbrdf -p MODULE``)
            import inspect

            wants = "registry" in inspect.signature(check).parameters
        except (TypeError, ValueError):
            wants = False
        for key, msg in (check(params, registry=self.reg) if wants else check(params)):
            self.problem(f"{owner}: {msg}", path + (key,) if key else path)

    def _params(self, declared: list[Param], given: dict, owner: str, path: tuple) -> dict:
        values, problems = resolve(declared, given, owner)
        for key, msg in problems:
            self.problem(msg, path + (key,) if key is not None else path)
        for p in declared:  # file parameters declared with extra={"path": True} are relative to the graph file
            v = values.get(p.name)
            if p.extra.get("path") and isinstance(v, str):
                values[p.name] = _yaml.relative_to(self.base, v)
        # Parameters that name another plugin, and parameters that are that plugin's parameters.
        for p in declared:
            category = p.extra.get("plugin_category")
            if category and isinstance(values.get(p.name), str) and values[p.name] not in self.reg.specs[category]:
                known = ", ".join(self.reg.names(category)) or "none installed"
                self.problem(f"{owner}: parameter {p.name!r}: unknown {category} {values[p.name]!r}; installed: {known}", path + (p.name,))
        for p in declared:
            of = p.extra.get("params_of")
            if of and isinstance(values.get(p.name), dict):
                target = next((q for q in declared if q.name == of), None)
                category = target.extra.get("plugin_category") if target else None
                other = values.get(of)
                if category and other in self.reg.specs[category]:
                    sub = self.reg.get(category, other)
                    values[p.name] = self._params(list(sub.params or ()), values[p.name], f"{category} {other!r}", path + (p.name,))
        return values

    # -- edges ----------------------------------------------------------------

    def _edges(self, nodes: dict[str, Node], raw: dict) -> None:
        for node in nodes.values():
            path = ("nodes", node.name, "in")
            for port_name, src in node.inputs.items():
                port = node.kind.port(port_name)
                if port is None:
                    ports = ", ".join(f"{p.name} ({p.kind_names})" for p in node.kind.inputs) or "none"
                    self.problem(f"node {node.name!r}: {node.kind.name} has no input {port_name!r}; its inputs: {ports}", path + (port_name,))
                    continue
                if not isinstance(src, str) or src not in raw:
                    self.problem(f"node {node.name!r}: input {port_name!r} refers to unknown node {src!r}; nodes: {', '.join(map(str, raw))}", path + (port_name,))
                    continue
                upstream = nodes.get(src)
                if upstream is not None and not port.accepts(upstream.kind.output):
                    self.problem(
                        f"node {node.name!r}: input {port_name!r} needs {port.kind_names}, but node {src!r} "
                        f"({upstream.kind.name}) produces {upstream.kind.output.kind}",
                        path + (port_name,),
                    )
            for port in node.kind.inputs:
                if port.name not in node.inputs and not port.optional:
                    self.problem(f"node {node.name!r}: missing input {port.name!r} ({port.kind_names}) in 'in:'", ("nodes", node.name))

    def _topological(self, nodes: dict[str, Node]) -> list[str]:
        order: list[str] = []
        state: dict[str, int] = {}  # 1 visiting, 2 done
        reported: set[frozenset] = set()

        def visit(name: str, stack: list[str]) -> None:
            if state.get(name) == 2 or name not in nodes:
                return
            if state.get(name) == 1:
                cycle = stack[stack.index(name):] + [name]
                key = frozenset(cycle)
                if key not in reported:
                    reported.add(key)
                    self.problem(f"cycle: {' -> '.join(cycle)}", ("nodes", name))
                return
            state[name] = 1
            for src in nodes[name].inputs.values():
                if isinstance(src, str):
                    visit(src, stack + [name])
            state[name] = 2
            order.append(name)

        for name in nodes:
            visit(name, [])
        return order
