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

Variables and overrides (docs/graphs.md): ``${name}`` in any value is replaced
by the variable ``name``, declared in a top-level ``variables:`` mapping with
its default (``null``: required), and ``overrides`` (``sbrdf run --set
fit.params.model_params.lobes=2``) replace values by dotted path before that;
both happen on the parsed document, before validation, so the result is
validated, and tokenized, exactly as if it had been written in the file.  A
graph without ``variables:`` and overrides is read as before.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import yaml

from . import _yaml
from .contracts import optional
from .errors import GraphError, Problem
from .params import Param, check_model_values, resolve
from .registry import Registry, default_registry
from .store import NODE_NAME

if TYPE_CHECKING:
    from .nodes.base import NodeKind

#: fsspec protocols that can only be read: a store on one passes ``exists`` and fails at the first write.
READ_ONLY_PROTOCOLS = frozenset({"http", "https", "github", "git", "tar", "libarchive", "reference", "data", "zip"})

TOP_KEYS = ("name", "store", "nodes", "description", "limits", "variables", "allow_outside_store")
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
    #: The variables' values this graph was validated with (defaults included), as substituted.
    variables: dict[str, Any] = field(default_factory=dict)
    #: The overrides applied (``"fit.params.model_params.lobes": 2``), in the order given.
    overrides: dict[str, Any] = field(default_factory=dict)
    #: Where plugin output paths may lie outside the store: ``(anywhere, folders)`` from ``allow_outside_store``.
    outside_store: tuple[bool, tuple[str, ...]] = (False, ())

    def url(self, node: str) -> str:
        """Where ``node``'s artifact lives."""
        return self.store.rstrip("/") + "/" + node


#: ``${name}`` (``$${name}`` is the literal text ``${name}``).
VARIABLE = re.compile(r"\$(\$?)\{([^}]*)\}")
VARIABLE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")

Overrides = Mapping[str, Any] | Iterable[str]


def load_graph(source: str | os.PathLike, registry: Registry | None = None, store: str | None = None,
               variables: Mapping[str, Any] | None = None, overrides: Overrides | None = None) -> Graph:
    """Load and validate a graph from a file path (or YAML text containing a newline).

    ``variables`` gives values to the graph's declared ``variables:``; a string
    is read as command-line text (:func:`variable_value`).  ``overrides`` are
    ``"node.params.key=value"`` strings (the value read by :func:`parse_value`)
    or a mapping of dotted path to value (used as it is).

    Raises :class:`~sbrdf_core.errors.GraphError` listing every problem.
    """
    registry = registry or default_registry()
    text, file, base = _read(source)
    return _Validator(text, file, base, registry, store, variables, overrides).run()


def _read(source: str | os.PathLike) -> tuple[str, str, Path]:
    src = str(source)
    if "\n" in src:
        return src, "<graph>", Path.cwd()
    path = Path(src)
    try:
        text = _yaml.read_text(path)  # UTF-8 (or UTF-16/32 with a BOM); a binary or Latin-1 file is a file:line error
    except OSError as e:
        raise GraphError([Problem(f"cannot read graph file: {e.strerror}", str(path))]) from None
    except yaml.YAMLError as e:
        raise GraphError([_yaml.syntax_problem(e, str(path))]) from None
    return text, str(path), path.resolve().parent


def parse_value(text: str) -> Any:
    """A value given on the command line, read as a YAML scalar or flow collection: ``3`` is a number,
    ``[1, 2]`` a list, ``{a: 1}`` a mapping, ``true`` a boolean; text that is not such YAML (or is empty) stays text."""
    if not text.strip():
        return text
    try:
        value, _ = _yaml.load(text)
    except yaml.YAMLError:
        return text
    return value


def variable_value(text: Any, default: Any) -> Any:
    """A variable's value from the command line or a batch CSV: kept as text where the declared default is
    text, otherwise read by :func:`parse_value` (``seed=3`` is the number 3).  Non-strings pass through."""
    if not isinstance(text, str) or isinstance(default, str):
        return text
    return parse_value(text)


def _as_text(value: Any) -> str:
    """A value as it would be written inside a YAML string."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool) or value is None:
        return {True: "true", False: "false", None: "null"}[value]
    if isinstance(value, (int, float)):
        return repr(value)
    return yaml.safe_dump(value, default_flow_style=True, width=10**9).strip()


def declared_variables(source: str | os.PathLike) -> dict[str, Any]:
    """The ``variables:`` a graph declares, name -> default (``None``: required); ``{}`` when it declares none
    or cannot be read (its validation reports that)."""
    try:
        doc, _ = _yaml.load(_read(source)[0])
    except (GraphError, yaml.YAMLError):
        return {}
    decl = doc.get("variables") if isinstance(doc, dict) else None
    return {str(k): v for k, v in decl.items()} if isinstance(decl, dict) else {}


def graph_store(source: str | os.PathLike, variables: Mapping[str, Any] | None = None,
                overrides: Overrides | None = None) -> str:
    """The graph's ``store:`` with overrides applied, its variables substituted and a local path resolved from
    the graph's folder (what :func:`load_graph` would use), without validating the rest.  Raises :class:`GraphError`."""
    text, file, base = _read(source)
    v = _Validator(text, file, base, default_registry(), None, variables, overrides)
    try:
        doc, v.loc = _yaml.load(text)
    except yaml.YAMLError as e:
        raise GraphError([_yaml.syntax_problem(e, file)]) from None
    if not isinstance(doc, dict):
        raise GraphError([Problem("a graph must be a mapping with 'name', 'store' and 'nodes'", file, 1)])
    for dotted, value, given in v.overrides:
        v._override(doc, dotted, value, given)
    values = v._variables(doc)
    v.problems = []  # only the store matters here: variables it does not use may have no value yet
    store = v._substitute(doc.get("store"), ("store",), values)
    if v.problems:
        raise GraphError(v.problems)
    if not isinstance(store, str) or not store:
        raise GraphError([Problem("graph needs a 'store'", file, v.loc.line(("store",)))])
    if (m := VARIABLE.search(store)) and not m.group(1):
        raise GraphError([Problem(f"store {store!r}: variable ${{{m.group(2)}}} has no value here (a batch's root "
                                  f"store is the graph's store, which may use only variables with defaults or "
                                  f"given by --var)", file, v.loc.line(("store",)))])
    if "://" in store:
        return store
    local = Path(store)
    return str((local if local.is_absolute() else base / local).resolve())


class _Validator:
    def __init__(self, text: str, file: str, base: Path, registry: Registry, store: str | None,
                 variables: Mapping[str, Any] | None = None, overrides: Overrides | None = None):
        self.text, self.file, self.base, self.reg, self.store_override = text, file, base, registry, store
        self.given = dict(variables or {})
        self.overrides: list[tuple[str, Any, str | None]]
        if isinstance(overrides, Mapping):
            self.overrides = [(str(k), v, f"{k}={_as_text(v)}") for k, v in overrides.items()]
        else:
            self.overrides = []
            for item in overrides or ():
                key, eq, raw = str(item).partition("=")
                self.overrides.append((key.strip(), parse_value(raw) if eq else None, str(item) if eq else None))
        self.problems: list[Problem] = []
        self.origins: dict[tuple, str] = {}  # a value's path -> where it came from (--set, ${variable})
        self.variables: dict[str, Any] = {}
        self.broken: set[tuple] = set()  # paths holding a ${variable} that has no value
        self.applied: dict[str, Any] = {}  # overrides applied: dotted path -> value

    def problem(self, message: str, path: tuple = (), line: int | None = None) -> None:
        if path and any(path[:len(b)] == b for b in self.broken):
            return  # a ${variable} without a value there, reported already: no second problem about its text
        origin = next((o for p, o in self.origins.items() if path[:len(p)] == p), None) if path else None
        if origin:
            message = f"{message} ({origin})"
        self.problems.append(Problem(message, self.file, line if line is not None else self.loc.line(path)))

    # -- variables and overrides ------------------------------------------------------

    def _variables(self, doc: dict) -> dict[str, tuple[Any, str]]:
        """Each declared variable's (value, text), from what was given or its default; problems for the rest."""
        decl = doc.get("variables")
        if decl is None:
            decl = {}
        if not isinstance(decl, dict):
            self.problem("'variables' must be a mapping of variable name -> default (null or nothing: required)",
                         ("variables",))
            decl = {}
        values: dict[str, tuple[Any, str]] = {}
        for name, default in decl.items():
            if not isinstance(name, str) or not VARIABLE_NAME.fullmatch(name):
                self.problem(f"variable name {name!r} is not an identifier (a letter or '_', then letters, digits "
                             f"or '_')", ("variables", name))
                continue
            if name in self.given:
                given = self.given[name]
                value = variable_value(given, default)
                values[name] = (value, given if isinstance(given, str) else _as_text(value))
            elif default is not None:
                values[name] = (default, _as_text(default))
            else:
                self.problem(f"variable {name!r} is required (declared without a default) and was given no value: "
                             f"pass --var {name}=VALUE, or a {name!r} column in the --batch CSV", ("variables", name))
        declared = ", ".join(map(str, decl)) or "none"
        for name in self.given:
            if name not in decl:
                self.problem(f"a value was given for variable {name!r}, but the graph declares no such variable; "
                             f"declared: {declared} (declare it under 'variables:')", ("variables",) if decl else (),
                             line=None if decl else 1)
        self.declared = set(map(str, decl))
        return values

    def _substitute(self, value: Any, path: tuple, values: dict[str, tuple[Any, str]]) -> Any:
        if isinstance(value, dict):
            return {k: self._substitute(v, path + (k,), values) for k, v in value.items()}
        if isinstance(value, list):
            return [self._substitute(v, path + (i,), values) for i, v in enumerate(value)]
        if not isinstance(value, str) or "${" not in value:
            return value
        used: list[str] = []

        def one(m: re.Match) -> str | None:
            name = m.group(2).strip()
            if m.group(1):  # $${x}: the text ${x}
                return None
            if not VARIABLE_NAME.fullmatch(name):
                self.problem(f"${{{m.group(2)}}} is not a variable reference: a variable's name is an identifier "
                             f"(write $${{...}} for the text ${{...}})", path)
                return None
            if name not in values:
                if name not in getattr(self, "declared", ()):  # a declared one without a value is reported once
                    known = ", ".join(sorted(getattr(self, "declared", values))) or "none"
                    self.problem(f"undefined variable ${{{name}}}: declare it under 'variables:' (with a default, or "
                                 f"null for a required one); declared: {known}", path)
                return None
            used.append(f"${{{name}}} = {values[name][1]!r}")
            return name

        whole = VARIABLE.fullmatch(value)
        if whole and not whole.group(1):
            name = one(whole)
            if name is None:
                self.broken.add(path)
                return value
            self.origins.setdefault(path, "from " + used[0])
            return values[name][0]
        out, pos = [], 0
        for m in VARIABLE.finditer(value):
            out.append(value[pos:m.start()])
            name = one(m)
            if name is None and not m.group(1):
                self.broken.add(path)
            out.append(values[name][1] if name is not None else (m.group(0)[1:] if m.group(1) else m.group(0)))
            pos = m.end()
        out.append(value[pos:])
        if used:
            self.origins.setdefault(path, "from " + ", ".join(used))
        return "".join(out)

    def _override(self, doc: dict, dotted: str, value: Any, given: str | None) -> None:
        """``--set node.params.key=value`` (``node.key`` is short for ``node.params.key``) or ``--set store=...``."""
        what = f"--set {given or dotted}"
        parts = [p for p in dotted.split(".")]
        if given is None:
            self.problems.append(Problem(f"{what}: an override is PATH=VALUE (e.g. fit.params.iterations=50)", self.file))
            return
        if not dotted or not all(parts):
            self.problems.append(Problem(f"{what}: {dotted!r} is not a dotted path (node.params.key)", self.file))
            return
        nodes: dict = doc["nodes"] if isinstance(doc.get("nodes"), dict) else {}
        if parts[0] in nodes:
            if len(parts) == 1:
                self.problems.append(Problem(f"{what}: name a key of node {parts[0]!r}: {parts[0]}.params.NAME (or "
                                             f"{parts[0]}.NAME for a parameter), {parts[0]}.plugin, {parts[0]}.in.PORT",
                                             self.file))
                return
            if parts[1] not in NODE_KEYS:
                parts.insert(1, "params")
            path: tuple = ("nodes",) + tuple(parts)
            container: Any = doc
        elif parts[0] in TOP_KEYS and parts[0] not in ("nodes", "variables"):
            path, container = tuple(parts), doc
        else:
            self.problems.append(Problem(f"{what}: the graph has no node {parts[0]!r}; nodes: "
                                         f"{', '.join(map(str, nodes)) or 'none'} (or a top-level key: store, name, "
                                         f"description, limits)", self.file))
            return
        for i, key in enumerate(path):
            last = i == len(path) - 1
            if isinstance(container, list):
                try:
                    index = int(key)
                    container[index]
                except (ValueError, IndexError):
                    self.problems.append(Problem(f"{what}: {'.'.join(map(str, path[1:i + 1]))} is not an index of "
                                                 f"the list at {'.'.join(map(str, path[1:i]))} ({len(container)} items)",
                                                 self.file, self.loc.line(path[:i])))
                    return
                path = path[:i] + (index,) + path[i + 1:]
                key = index
            elif not isinstance(container, dict):
                self.problems.append(Problem(f"{what}: {'.'.join(map(str, path[1:i]))} is "
                                             f"{type(container).__name__} {container!r}, not a mapping with key {key!r}",
                                             self.file, self.loc.line(path[:i])))
                return
            if last:
                container[key] = value
            else:
                if isinstance(container, dict) and container.get(key) is None:
                    container[key] = {}
                container = container[key]
        self.origins[path] = f"set by {what}"
        self.applied[dotted] = value

    def _expand(self, doc: dict) -> dict:
        """Overrides, then ``${variables}``: the document as if both had been written in the file."""
        self.applied = {}
        for dotted, value, given in self.overrides:
            self._override(doc, dotted, value, given)
        if "variables" not in doc and not self.given and "${" not in self.text and not self.overrides:
            return doc  # a graph without variables: exactly as before
        values = self._variables(doc)
        self.variables = {k: v for k, (v, _) in values.items()}
        return {k: (v if k == "variables" else self._substitute(v, (k,), values)) for k, v in doc.items()}

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
        doc = self._expand(doc)
        for key in doc:
            if key not in TOP_KEYS:
                self.problem(f"unknown top-level key {key!r}; allowed: {', '.join(TOP_KEYS)}", (key,))
        name = doc.get("name")
        if not isinstance(name, str) or not name:
            self.problem("graph needs a 'name' (a string)", ("name",))
        store = self._store(doc)
        self.doc, self.store_url = doc, store  # what output-path parameters are checked against (_params)
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
            variables=self.variables,
            overrides=dict(self.applied),
            outside_store=self._outside_store(doc),
        )

    def _outside_store(self, doc: dict) -> tuple[bool, tuple[str, ...]]:
        from . import outputs

        anywhere, folders, _ = outputs.allowed_folders(doc.get(outputs.OPT_IN), self.base)
        return anywhere, tuple(map(str, folders))

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
        protocol = raw.split("://", 1)[0] if "://" in raw else "file"
        if protocol == "file":
            local = Path(raw.split("://", 1)[-1])
            local = local if local.is_absolute() else (self.base / local)
            try:
                url = str(local.resolve())
                probe = local
                while not probe.exists() and probe != probe.parent:
                    probe = probe.parent
            except (OSError, ValueError) as e:  # a name too long, a NUL byte, a loop of links
                self.problem(f"store {raw[:200]!r} cannot be opened: {getattr(e, 'strerror', None) or e}", ("store",))
                return ""
            if probe.exists() and not probe.is_dir():
                self.problem(f"store {raw!r} cannot be opened: {probe} is a file, not a directory", ("store",))
            elif not os.access(probe, os.W_OK | os.X_OK):
                self.problem(f"store {raw!r} cannot be opened: {probe} is not writable", ("store",))
            return url
        if protocol.lower() in READ_ONLY_PROTOCOLS:
            self.problem(f"store {raw!r} cannot be written: {protocol}:// is a read-only file system; a store is a "
                         f"local path or a writable URL (s3://, gs://, az://, memory://, ...)", ("store",))
            return raw
        import fsspec  # a URL only: a local store is checked without it

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
            self._requirements(spec, name, path + ("plugin",))
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

    def _requirements(self, spec, node: str, path: tuple) -> None:
        """Optional modules the plugin's implementation lists in ``requires`` and this environment lacks.

        Plugins import heavy dependencies only when they run, so without this a
        graph validates and then fails at that node, after the nodes before it
        have run; the message names the extra that installs the module.
        """
        import importlib.util

        from .extras import EXTRAS

        try:
            impl = self.reg.load(spec)
        except Exception:  # the registry reports broken plugins itself
            return
        for module in getattr(impl, "requires", ()) or ():
            top = module.partition(".")[0]
            try:
                found = importlib.util.find_spec(top) is not None
            except (ImportError, ValueError):
                found = False
            if not found:
                extra = EXTRAS.get(top, (top, top))[0]
                self.problem(f"node {node!r}: {spec.category} plugin {spec.name!r} needs the optional dependency "
                             f"{module!r}, which is not installed: pip install 'sbrdf[{extra}]'", path)

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
                if p.extra.get("output"):  # a path the plugin writes: confined to the store (sbrdf_core.outputs)
                    self._output_path(values[p.name], path + (p.name,))
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
        for p in declared:  # values of a BRDF model's parameters: checked against the model's own declarations
            of = p.extra.get("model_values_of")
            if of and isinstance(values.get(p.name), dict) and values[p.name]:
                self._model_values(p.name, values, of, owner, path)
        for p in declared:  # {device: NAME, params: {...}} inside a parameter: NAME's own declarations
            value = values.get(p.name)
            if p.schema is not None and isinstance(value, dict):
                self._nested_plugins(p.schema, value, path + (p.name,))
            elif p.values is not None and isinstance(value, dict):
                for key, sub in value.items():
                    if isinstance(sub, dict):
                        self._nested_plugins(p.values, sub, path + (p.name, key))
        return values

    def _nested_plugins(self, schema: tuple[Param, ...], value: dict, path: tuple) -> None:
        """A nested mapping naming a plugin (a key declared with ``plugin_category``) and giving its ``params``:
        the plugin must be installed and the parameters must follow its declarations.  Checked, not rewritten
        (like every nested schema: the graph's values and its cache tokens stay as written)."""
        for q in schema:
            category = q.extra.get("plugin_category")
            name = value.get(q.name)
            if not category or not isinstance(name, str):
                continue
            if name not in self.reg.specs.get(category, {}):
                known = ", ".join(self.reg.names(category)) or "none installed"
                self.problem(f"{'.'.join(map(str, path[3:] + (q.name,)))}: unknown {category} plugin {name!r}; "
                             f"installed: {known}", path + (q.name,))
                continue
            given = value.get("params")
            if any(r.name == "params" for r in schema) and isinstance(given, dict):
                sub = self.reg.get(category, name)
                self._params(list(sub.params or ()), given, f"{category} {name!r}", path + ("params",))

    def _model_values(self, name: str, values: dict, of: tuple[str, str], owner: str, path: tuple) -> None:
        """``params: {rho_d: 0.2}`` of the model named by parameter ``of[0]``, configured by ``of[1]``: each
        name one of the model's parameters, each value a finite number (or one per channel) within its bounds."""
        model_name, config = values.get(of[0]), values.get(of[1]) or {}
        if not isinstance(model_name, str) or model_name not in self.reg.specs["brdf-model"] or not isinstance(config, dict):
            return  # an unknown model or a bad configuration is reported already
        before = len(self.problems)
        try:
            model = self.reg.create("brdf-model", model_name, dict(config))
        except Exception as e:  # noqa: BLE001  (a configuration the declarations let through but the model refuses)
            if len(self.problems) == before:
                self.problem(f"{owner}: brdf-model {model_name!r} with {of[1]} {config!r} cannot be built: {e}",
                             path + (of[1],))
            return
        for key, msg in check_model_values(model, values[name], f"{name}"):
            self.problem(f"{owner}: {msg}", path + (name,) + ((key,) if key is not None else ()))

    def _output_path(self, value: str, path: tuple) -> None:
        """One parameter declared ``extra={"output": True}``: inside the store, beside the artifacts, unless the
        graph's ``allow_outside_store`` lets it out (which is logged, so ``validate`` shows it)."""
        from . import outputs

        doc, store = getattr(self, "doc", {}), getattr(self, "store_url", "")
        if not store:
            return  # no store: reported already
        if not hasattr(self, "_allowed"):
            self._allowed = outputs.allowed_folders(doc.get(outputs.OPT_IN), self.base)
            self._outputs: dict[str, tuple] = {}
            if self._allowed[2]:
                self.problem(self._allowed[2], (outputs.OPT_IN,))
        anywhere, folders, _ = self._allowed
        nodes = doc.get("nodes")
        nodes = nodes if isinstance(nodes, dict) else {}
        where = f"node {path[1]!r}: parameter {'.'.join(map(str, path[3:]))!r}"
        problem, outside = outputs.output_problem(value, store, map(str, nodes), anywhere, folders)
        if problem:
            self.problem(f"{where}: {problem}", path)
            return
        real = os.path.realpath(value)
        if real in self._outputs:
            self.problem(f"{where}: {value!r} is also written by {self._outputs[real][0]} (line "
                         f"{self.loc.line(self._outputs[real][1])}); each output path belongs to one node", path)
        self._outputs[real] = (where, path)
        if outside:
            import logging

            logging.getLogger(__name__).warning("%s:%s: %s writes %s, outside the store: allowed by '%s' (line %s)",
                                                self.file, self.loc.line(path), where, real, outputs.OPT_IN,
                                                self.loc.line((outputs.OPT_IN,)))

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
