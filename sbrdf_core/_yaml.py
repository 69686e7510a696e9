"""Safe YAML loading that remembers the line of every key.

Graphs are data: only PyYAML's safe constructors run, and duplicate keys
(which plain PyYAML silently overwrites) are reported as problems.
"""

from __future__ import annotations

from typing import Any

import yaml

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
