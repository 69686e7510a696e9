"""Safe, bounded YAML loading that remembers the line of every key.

Graphs and scenes are data: only PyYAML's safe constructors run, and
everything a hostile or damaged file could do to the loader ends in a
:class:`LoadError` at a ``file:line``, never a traceback or a hang:

- duplicate keys (which plain PyYAML silently overwrites) are reported as problems;
- text that is not UTF-8 (or UTF-16/32 with a byte-order mark): a binary
  file, Latin-1, UTF-16 without a BOM, names the byte and its line;
- nesting deeper than :data:`MAX_DEPTH` collections;
- aliases that expand to more than :data:`MAX_ALIAS_VALUES` values ("billion
  laughs"), and an alias inside its own anchor (a recursive document);
- a list or mapping used as a mapping key;
- any tag other than plain YAML data (:data:`ALLOWED_TAGS`), e.g. ``!!python/object``;
- a scalar its constructor cannot convert (an integer of more digits than
  Python converts to ``int``, a date that does not exist);
- a path that is not a regular file, or larger than the text limit
  (:mod:`sbrdf_core.input_files`).
"""

from __future__ import annotations

import codecs
from pathlib import Path as _FilePath
from typing import Any

import yaml

from . import input_files
from .errors import Problem

Path = tuple[Any, ...]

#: Deepest nesting of lists and mappings a graph or scene file may have.
MAX_DEPTH = 64
#: Most values (scalars, lists, mappings) that aliases may expand to in one document.
MAX_ALIAS_VALUES = 100_000

_CORE = "tag:yaml.org,2002:"
#: Tags a document may carry: plain YAML data, nothing that constructs objects.
ALLOWED_TAGS = frozenset(_CORE + t for t in (
    "null", "bool", "int", "float", "str", "timestamp", "binary", "merge", "value", "map", "seq"))


class LoadError(yaml.MarkedYAMLError):
    """A document the loader refuses (not a syntax error): ``problem`` at ``problem_mark``."""

    def __init__(self, problem: str, line: int | None = None, column: int | None = None):
        mark = yaml.Mark("<document>", 0, line, column or 0, None, None) if line is not None else None
        super().__init__(problem=problem, problem_mark=mark)


class Located:
    """A loaded YAML document plus ``lines[path] -> 1-based line``."""

    def __init__(self) -> None:
        self.lines: dict[Path, int] = {}
        self.duplicates: list[tuple[Path, int]] = []

    def line(self, path: Path) -> int | None:
        """Line of ``path``, falling back to its nearest located parent."""
        path = tuple(path)
        while path:
            if path in self.lines:
                return self.lines[path]
            path = path[:-1]
        return self.lines.get((), None)


class _BoundedLoader(yaml.SafeLoader):
    """The safe loader with a bound on nesting depth (PyYAML's composer recurses per level)."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise LoadError(f"nesting deeper than {MAX_DEPTH} levels of lists and mappings", mark.line, mark.column)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def read_text(path: str | _FilePath) -> str:
    """A graph or scene file's text; raises :class:`LoadError` (with the line) if it cannot be decoded.

    UTF-8 (with or without a byte-order mark) is read, and UTF-16 or UTF-32
    with a byte-order mark as YAML allows; anything else is refused, naming the
    first byte that cannot be decoded.  ``OSError`` passes through, including
    :class:`~sbrdf_core.input_files.InputFileError` for a path that is not a
    regular file (``/dev/zero``, a FIFO: read whole or blocking) or is larger
    than the text limit (:func:`sbrdf_core.input_files.limit`).
    """
    data = input_files.read_bytes(path, text=True)
    for bom, encoding in ((codecs.BOM_UTF32_LE, "utf-32"), (codecs.BOM_UTF32_BE, "utf-32"), (codecs.BOM_UTF8, "utf-8-sig"),
                          (codecs.BOM_UTF16_LE, "utf-16"), (codecs.BOM_UTF16_BE, "utf-16")):
        if data.startswith(bom):
            try:
                return data.decode(encoding)
            except UnicodeDecodeError as e:
                raise LoadError(f"not valid {encoding.upper()} text although the file starts with its byte-order "
                                f"mark: {e.reason} at byte {e.start}", 0) from None
    nul = data.find(b"\x00")
    if nul >= 0:
        line, col = _byte_position(data, nul)
        raise LoadError(f"a NUL byte at line {line + 1}, column {col + 1}: a binary file, or UTF-16/32 text without a "
                        "byte-order mark; graph and scene files are UTF-8 YAML", line, col)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line, col = _byte_position(data, e.start)
        raise LoadError(f"not UTF-8 text: byte 0x{data[e.start]:02x} at line {line + 1}, column {col + 1} cannot be "
                        "decoded (Latin-1 or another 8-bit encoding?); save the file as UTF-8", line, col) from None


def _byte_position(data: bytes, index: int) -> tuple[int, int]:
    """0-based line and column of byte ``index``."""
    return data.count(b"\n", 0, index), index - (data.rfind(b"\n", 0, index) + 1)


def load(text: str) -> tuple[Any, Located]:
    """Parse ``text``; raises ``yaml.YAMLError`` (with its mark) on syntax errors and :class:`LoadError` on refusals."""
    loc = Located()
    try:
        node = yaml.compose(text, Loader=_BoundedLoader)
    except yaml.reader.ReaderError as e:  # a control character: the mark PyYAML gives has no line
        line = text.count("\n", 0, e.position)
        col = e.position - (text.rfind("\n", 0, e.position) + 1)
        raise LoadError(f"character #x{e.character:04x} at line {line + 1}, column {col + 1} is not allowed in YAML "
                        "(a binary file?)", line, col) from None
    except RecursionError:
        raise LoadError(f"nesting too deep (more than {MAX_DEPTH} levels, or a long chain of merges)", 0) from None
    if node is None:
        return None, loc
    try:
        return _Converter(loc).convert(node, ()), loc
    except RecursionError:
        raise LoadError(f"nesting too deep (more than {MAX_DEPTH} levels, or a long chain of merges)", 0) from None


def _tag_name(tag: str) -> str:
    return "!!" + tag[len(_CORE):] if tag.startswith(_CORE) else tag


class _Converter:
    def __init__(self, loc: Located):
        self.loc = loc
        self.ctor = yaml.SafeLoader("")
        self.seen: set[int] = set()  # nodes converted at least once: meeting one again is an alias
        self.active: set[int] = set()  # nodes being converted: meeting one again is a recursive alias
        self.in_alias = 0
        self.alias_values = 0

    def refuse(self, node: yaml.Node, message: str):
        raise LoadError(message, node.start_mark.line, node.start_mark.column)

    def convert(self, node: yaml.Node, path: Path) -> Any:
        if len(path) > MAX_DEPTH:  # aliases can nest what each anchor kept shallow
            self.refuse(node, f"nesting deeper than {MAX_DEPTH} levels of lists and mappings (through aliases)")
        key = id(node)
        if key in self.active:
            self.refuse(node, "recursive alias: an anchor's value contains an alias of itself")
        alias = key in self.seen
        self.seen.add(key)
        self.in_alias += alias
        if self.in_alias:
            self.alias_values += 1
            if self.alias_values > MAX_ALIAS_VALUES:
                self.refuse(node, f"aliases expand to more than {MAX_ALIAS_VALUES} values (an alias bomb?)")
        if node.tag not in ALLOWED_TAGS:
            self.refuse(node, f"tag {_tag_name(node.tag)} is not allowed: graph and scene files hold plain data "
                              "(mappings, lists, strings, numbers, booleans, null)")
        self.active.add(key)
        try:
            return self._convert(node, path)
        finally:
            self.active.discard(key)
            self.in_alias -= alias

    def _convert(self, node: yaml.Node, path: Path) -> Any:
        loc, ctor = self.loc, self.ctor
        loc.lines.setdefault(path, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            try:
                ctor.flatten_mapping(node)  # merge keys (<<) the safe way
            except yaml.constructor.ConstructorError as e:
                self.refuse(node, f"merge key (<<): {e.problem}")
            out: dict[Any, Any] = {}
            for knode, vnode in node.value:
                if not isinstance(knode, yaml.ScalarNode):
                    what = "a list" if isinstance(knode, yaml.SequenceNode) else "a mapping"
                    self.refuse(knode, f"{what} cannot be a mapping key; keys are names, numbers or strings")
                if knode.tag not in ALLOWED_TAGS:
                    self.refuse(knode, f"tag {_tag_name(knode.tag)} is not allowed: graph and scene files hold plain "
                                       "data (mappings, lists, strings, numbers, booleans, null)")
                key = self._scalar(knode)
                if key in out:
                    loc.duplicates.append((path + (key,), knode.start_mark.line + 1))
                    continue
                loc.lines[path + (key,)] = knode.start_mark.line + 1
                out[key] = self.convert(vnode, path + (key,))
            return out
        if isinstance(node, yaml.SequenceNode):
            return [self.convert(v, path + (i,)) for i, v in enumerate(node.value)]
        return self._scalar(node)

    def _scalar(self, node: yaml.ScalarNode) -> Any:
        try:
            return self.ctor.construct_object(node, deep=True)
        except yaml.constructor.ConstructorError as e:
            self.refuse(node, f"{e.problem}")
        except (ValueError, OverflowError) as e:  # int() of more digits than Python converts, a date out of range
            value = node.value if len(node.value) <= 40 else f"{node.value[:20]}...({len(node.value)} characters)"
            reason = str(e).split(";")[0]  # not Python's advice on raising its own limit
            self.refuse(node, f"value {value!r} cannot be read as {_tag_name(node.tag)[2:]}: {reason}")


def syntax_problem(error: yaml.YAMLError, file: str) -> Problem:
    """A YAML syntax error, or a :class:`LoadError`, as a :class:`~sbrdf_core.errors.Problem` at its line."""
    mark = getattr(error, "problem_mark", None)
    what = error.problem if isinstance(error, LoadError) else \
        f"YAML syntax error: {getattr(error, 'problem', None) or error}"
    return Problem(what, file, mark.line + 1 if mark is not None else None)


def relative_to(base: _FilePath, value: str) -> str:
    """A file named in a YAML document, resolved from the document's folder unless absolute or a URL."""
    return value if "://" in value or _FilePath(value).is_absolute() else str(base / value)
