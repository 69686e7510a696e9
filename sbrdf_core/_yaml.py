"""Safe YAML loading that remembers the line of every key.

Graphs are data: only PyYAML's safe constructors run, and duplicate keys
(which plain PyYAML silently overwrites) are reported as problems.
"""

from __future__ import annotations

from pathlib import Path as _FilePath
from typing import Any

import yaml

from .errors import Problem

Path = tuple[Any, ...]


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


def load(text: str) -> tuple[Any, Located]:
    """Parse ``text``; raises ``yaml.YAMLError`` (with its mark) on syntax errors."""
    loc = Located()
    node = yaml.compose(text, Loader=yaml.SafeLoader)
    if node is None:
        return None, loc
    constructor = yaml.SafeLoader("")
    return _convert(node, (), loc, constructor), loc


def _convert(node: yaml.Node, path: Path, loc: Located, ctor: yaml.SafeLoader) -> Any:
    loc.lines.setdefault(path, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        ctor.flatten_mapping(node)  # merge keys (<<) the safe way
        out: dict[Any, Any] = {}
        for knode, vnode in node.value:
            key = ctor.construct_object(knode, deep=True)
            if key in out:
                loc.duplicates.append((path + (key,), knode.start_mark.line + 1))
                continue
            loc.lines[path + (key,)] = knode.start_mark.line + 1
            out[key] = _convert(vnode, path + (key,), loc, ctor)
        return out
    if isinstance(node, yaml.SequenceNode):
        return [_convert(v, path + (i,), loc, ctor) for i, v in enumerate(node.value)]
    return ctor.construct_object(node, deep=True)


def syntax_problem(error: yaml.YAMLError, file: str) -> Problem:
    """A YAML syntax error as a :class:`~sbrdf_core.errors.Problem` at its line."""
    mark = getattr(error, "problem_mark", None)
    return Problem(f"YAML syntax error: {getattr(error, 'problem', None) or error}", file,
                   mark.line + 1 if mark is not None else None)


def relative_to(base: _FilePath, value: str) -> str:
    """A file named in a YAML document, resolved from the document's folder unless absolute or a URL."""
    return value if "://" in value or _FilePath(value).is_absolute() else str(base / value)
