"""Where a plugin may write a path it is given as a parameter (docs/graphs.md, "Output paths").

A node's artifact is written by the runner below ``<store>/<node>``, proven
inside the store by :func:`sbrdf_core.store.inside_store`.  Some plugins also
write a path named by a parameter (the separable fitters' ``factors``); such a
parameter is declared ``Param(..., extra={"path": True, "output": True})``
and obeys one rule, checked at validation with the parameter's line:

* the path, ``..`` and symbolic links resolved, lies inside the graph's store,
  is not the store root, not a store file (``.sbrdf.lock``), and not inside
  the artifact directory of any node of the graph (nor any other directory
  marked as an artifact); two nodes may not name the same path;
* a path outside the store is refused unless the graph opts in with a
  top-level ``allow_outside_store:`` -- ``true`` (anywhere) or a list of
  folders (relative to the graph file) the outputs may lie in; ``validate``
  logs every output it lets out that way.  The opt-in never lets an output
  into the store root or another node's artifact.

At run time a plugin checks the path it is about to replace with
:func:`check_replaceable` (a graph built in Python skips validation): it may
replace only what it wrote itself, never a symbolic link, a store root or an
artifact directory.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path

from .store import ARTIFACT_MARKER

#: The top-level graph key that lets output paths out of the store.
OPT_IN = "allow_outside_store"
#: Files at a store's root that mark it as one (the run lock and its holder record).
STORE_FILES = (".sbrdf.lock", ".sbrdf.lock.json")


class OutputPathError(ValueError):
    """An output path a plugin may not write or replace; the message names the path and why."""


def _real(path: str | os.PathLike) -> Path:
    return Path(os.path.realpath(os.path.expanduser(str(path))))


def _inside(path: Path, root: Path) -> bool:
    return path == root or root in path.parents


def is_store_root(path: Path) -> bool:
    """Whether ``path`` is the root of an sbrdf store (it holds the run lock files)."""
    return any((path / name).exists() for name in STORE_FILES)


def is_artifact(path: Path) -> bool:
    """Whether ``path`` is an artifact directory: its marker file, or (stores written before markers) a
    zarr group whose ``kind`` is a registered artifact kind."""
    if (path / ARTIFACT_MARKER).exists():
        return True
    from .artifacts import KINDS

    try:
        attrs = json.loads((path / "zarr.json").read_text()).get("attributes") or {}
    except (OSError, ValueError, AttributeError):
        return False
    return attrs.get("kind") in KINDS


def enclosing(path: Path, stop: Path | None = None) -> tuple[str, Path] | None:
    """The first store root or artifact directory among ``path``'s parents (up to ``stop``), as ``(what, dir)``."""
    for parent in path.parents:
        if stop is not None and not _inside(parent, stop):
            break
        if is_artifact(parent):
            return "artifact", parent
        if is_store_root(parent):
            return "store", parent
    return None


def allowed_folders(value, base: Path) -> tuple[bool, list[Path], str | None]:
    """``allow_outside_store:`` -> (anywhere, folders, problem).  ``None``/``false``: nothing allowed."""
    if value is None or value is False:
        return False, [], None
    if value is True:
        return True, [], None
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not all(isinstance(v, str) and v and "://" not in v for v in items):
        return False, [], (f"'{OPT_IN}' must be true, false, or a list of local folders (relative to the graph "
                           f"file) that plugin output paths may lie in; got {value!r}")
    return False, [_real(v if Path(v).expanduser().is_absolute() else base / v) for v in items], None


def output_problem(value: str, store: str, nodes: Iterable[str], anywhere: bool = False,
                   folders: Iterable[Path] = ()) -> tuple[str | None, bool]:
    """The confinement rule for one output path (already relative to the graph file).

    Returns ``(problem or None, outside)``: ``outside`` is true when the path is
    allowed only by the graph's ``allow_outside_store``.
    """
    if "://" in value:
        return f"{value!r} is not a local path; plugin outputs are written inside the store", False
    path = _real(value)
    if "://" in store:
        root = None
    else:
        root = _real(store)
        if path == root:
            return (f"{value!r} is the store root {root}; writing there would replace the whole store: name a "
                    f"path inside it (e.g. {root}/<name>.zarr)"), False
        if _inside(path, root):
            first = path.relative_to(root).parts[0]
            if first in set(nodes):
                return (f"{value!r} lies inside node {first!r}'s artifact {root / first}; name a path beside the "
                        f"artifacts (e.g. {root}/<name>.zarr)"), False
            if first in STORE_FILES:
                return f"{value!r} is the store's own file {root / first}", False
            # Any artifact on the way down from the store root (one another graph wrote there, too), or the path.
            inner = next((d for d in [path, *path.parents] if d != root and _inside(d, root) and d.is_dir()
                          and is_artifact(d)), None)
            if inner is not None:
                what = "is" if inner == path else "lies inside"
                return f"{value!r} {what} the artifact directory {inner}; name a path beside the artifacts", False
            return None, False
    hit = enclosing(path) or (("store", path) if path.is_dir() and is_store_root(path) else None)
    if hit is not None:
        what = "an artifact directory" if hit[0] == "artifact" else "another store"
        return f"{value!r} resolves to {path}, inside {what} ({hit[1]}); refusing to write there", False
    if anywhere or any(_inside(path, f) for f in folders):
        return None, True
    where = f"the store {root}" if root is not None else f"the store {store} (not a local path)"
    return (f"{value!r} resolves to {path}, outside {where}; name a path inside the store, or let this graph write "
            f"there with a top-level '{OPT_IN}: [<folder>]' (or '{OPT_IN}: true')"), False


def check_replaceable(path: str | os.PathLike, is_own, what: str) -> None:
    """Before a plugin replaces ``path`` at run time: raise :class:`OutputPathError` unless it is missing, or is
    what this plugin wrote (``is_own(path)``) and not a symbolic link, a store root or inside an artifact."""
    p = Path(os.path.abspath(os.path.expanduser(str(path))))
    real = _real(p)
    inner = next((d for d in real.parents if is_artifact(d)), None)
    if inner is not None:  # beside the artifacts of a store is fine; inside one of them is not
        raise OutputPathError(f"{p}: resolves to {real}, inside the artifact directory {inner}; refusing to write "
                              f"{what} there")
    if p.is_symlink():
        raise OutputPathError(f"{p} is a symbolic link (to {os.readlink(p)}); refusing to replace it with {what}: "
                              f"remove the link or name another path")
    if not p.exists():
        return
    if p.is_dir() and (is_store_root(p) or is_artifact(p)):
        raise OutputPathError(f"{p} is {'a store root' if is_store_root(p) else 'an artifact directory'}; refusing to "
                              f"replace it with {what}")
    if not is_own(p):
        kind = "directory" if p.is_dir() else "file"
        raise OutputPathError(f"{p} exists and is not {what} (a {kind} something else wrote); refusing to replace "
                              f"it: move it away or name another path")
