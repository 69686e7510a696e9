"""Up-front estimates of what each node of a graph will write and hold, checked before anything runs.

A graph of 16384² texels × 100000 poses is valid parameter by parameter and
would write ~440 TB: without an estimate it validates and then grows until
the disk fills or the process is killed.  :func:`check` runs at the end of
graph validation (``sbrdf validate`` and ``sbrdf run``) and refuses such a
graph with the node named.

Estimates follow the artifact kinds' arrays (``artifacts.py``), uncompressed,
from the sizes a graph states: ``texels: [U, V]`` and ``poses: N`` parameters
(synthetic captures, ``SampleModel``), a Register's ``texels``, and what flows
from upstream (a texel-aligned Register keeps its capture's grid).  A node
whose sizes only its input files know (a capture folder, a rig) is not
estimated, nor is anything downstream of it that states no size itself.

Limits (docs/graphs.md, "Size limits"):

- stored bytes: the sum over the nodes not yet in the store must fit the
  free space of the store's filesystem (local stores), or ``max_bytes``;
- memory: the peak one task of a node holds (one pose image, one texel tile
  of every pose, one Register pose block) must fit the machine's physical
  memory, or ``max_memory``.

``max_bytes`` and ``max_memory`` come from the graph's ``limits:`` mapping or
the ``SBRDF_MAX_BYTES`` / ``SBRDF_MAX_MEMORY`` environment variables (the
graph wins); a size is a number of bytes or a string such as ``"500 GB"`` or
``"2 TiB"``.
"""

from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .nodes.base import NodeKind

#: Environment variables that set the limits when the graph's ``limits:`` does not.
ENV = {"max_bytes": "SBRDF_MAX_BYTES", "max_memory": "SBRDF_MAX_MEMORY"}
LIMIT_KEYS = tuple(ENV)

_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12, "pb": 10**15,
          "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40, "pib": 2**50}


@dataclass
class Estimate:
    """What one node writes (``bytes``) and holds in one task (``peak``), and the sizes it passes on."""

    bytes: int
    peak: int | None = None
    how: str = ""
    dims: dict[str, Any] = field(default_factory=dict)  # poses, texels (U, V), image (H, W)


def parse_size(value: Any) -> int:
    """Bytes from a number or a string like ``"500 GB"``, ``"2TiB"``, ``"1e12"``; ``ValueError`` otherwise."""
    if isinstance(value, bool):
        raise ValueError(f"not a size: {value!r}")
    if isinstance(value, int) and value >= 2**63:  # beyond any disk; and a float of it may overflow
        raise ValueError(f"not a size: an integer of {value.bit_length()} bits is more than any disk or memory")
    if isinstance(value, (int, float)):
        if not (value == value and 0 < value < float("inf")):
            raise ValueError(f"not a positive size: {value!r}")
        return int(value)
    m = re.fullmatch(r"\s*([0-9.]+(?:[eE][-+]?\d+)?)\s*([A-Za-z]*)\s*", str(value))
    if not m or m.group(2).lower() not in _UNITS:
        raise ValueError(f"not a size: {value!r}; give bytes or a number with B, kB, MB, GB, TB, KiB, MiB, GiB or TiB")
    n = float(m.group(1)) * _UNITS[m.group(2).lower()]
    if not 0 < n < float("inf"):
        raise ValueError(f"not a positive size: {value!r}")
    return int(n)


def human(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if abs(n) < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n} B"  # pragma: no cover


def _grid(value: Any) -> tuple[int, int] | None:
    if isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(v, int) and v > 0 for v in value):
        return int(value[0]), int(value[1])
    return None


def _poses(value: Any) -> int | None:
    return int(value) if isinstance(value, int) and not isinstance(value, bool) and value > 0 else None


def estimate_node(kind: type[NodeKind], params: dict, inputs: dict[str, Estimate | None]) -> Estimate | None:
    """The estimate of one node: its kind's own ``estimate`` if it has one, else by its output artifact kind."""
    P: Any  # pose count: from the parameters or upstream, None when neither says
    own = getattr(kind, "estimate", None)
    if callable(own):
        return own(params, inputs)
    upstream = next((e for e in inputs.values() if e is not None and e.dims), None)
    up = upstream.dims if upstream else {}
    texels = _grid(params.get("texels"))
    poses = _poses(params.get("poses"))
    out = kind.output.kind
    if out == "CaptureSet":
        if texels is None or poses is None:
            return None
        (W, H), P = texels, poses
        return Estimate(P * H * W * 13 + P * 128, H * W * 32, f"{P} poses × {W}×{H} px × 13 B",
                        {"poses": P, "image": (H, W), "texels": texels})
    if out == "RegisteredStack":
        P = up.get("poses")
        grid = texels or up.get("texels")
        if P is None or grid is None:
            return None
        U, V = grid
        from .nodes.register import pose_block

        H, W = up.get("image", (V, U))
        k = pose_block((V, U), P)
        return Estimate(P * V * U * 13 + P * 256, k * V * U * 16 + H * W * 16 * 2, f"{P} poses × {U}×{V} texels × 13 B",
                        {"poses": P, "texels": (U, V)})
    if out == "SampledReflectance":
        P = poses or up.get("poses")
        grid = texels or up.get("texels")
        if P is None or grid is None:
            return None
        U, V = grid
        from .store import texel_tile

        t = texel_tile((V, U), P, channels=4)
        return Estimate(V * U * P * 13 + P * 48, 2 * t * t * P * 16, f"{U}×{V} texels × {P} poses × 13 B",
                        {"poses": P, "texels": (U, V)})
    if out == "ParamMaps" and up.get("texels"):
        U, V = up["texels"]
        P = up.get("poses", 1)
        from .store import texel_tile

        t = texel_tile((V, U), P, channels=4)
        return Estimate(V * U * 80, 4 * t * t * P * 16, f"{U}×{V} texels × ~80 B (parameter and error maps)",
                        {"texels": (U, V), "poses": P})
    if out == "TextureSet" and up.get("texels"):
        U, V = up["texels"]
        return Estimate(V * U * 40, V * U * 80, f"{U}×{V} texels × ~40 B", {"texels": (U, V)})
    return None


def limits_from(raw: Any) -> tuple[dict[str, int], list[tuple[str | None, str]]]:
    """The limits a graph's ``limits:`` and the environment set; problems as ``(key, message)``."""
    problems: list[tuple[str | None, str]] = []
    given: dict[str, Any] = {}
    if raw is not None and not isinstance(raw, dict):
        problems.append((None, f"'limits' must be a mapping with {' and/or '.join(LIMIT_KEYS)}, e.g. "
                               "{max_bytes: 500 GB}"))
    elif isinstance(raw, dict):
        for key in raw:
            if key not in LIMIT_KEYS:
                problems.append((key, f"unknown limit {key!r}; allowed: {', '.join(LIMIT_KEYS)}"))
        given = {k: raw[k] for k in LIMIT_KEYS if raw.get(k) is not None}
    out: dict[str, int] = {}
    for key, var in ENV.items():
        value, where = (given[key], f"limits: {key}") if key in given else (os.environ.get(var), var)
        if value is None or value == "":
            continue
        try:
            out[key] = parse_size(value)
        except ValueError as e:
            problems.append((key if key in given else None, f"{where}: {e}"))
    return out, problems


def _free_disk(store: str) -> int | None:
    if "://" in store and not store.startswith("file://"):
        return None
    probe = Path(store.split("://", 1)[-1])
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        return shutil.disk_usage(probe).free
    except OSError:
        return None


def _physical_memory() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def _stored(store: str, node: str) -> bool:
    """Whether ``node`` already has an artifact in a local store (its bytes are on the disk already)."""
    if "://" in store and not store.startswith("file://"):
        return False
    return (Path(store.split("://", 1)[-1]) / node / "zarr.json").exists()


def check(nodes: dict, order: list[str], store: str, limits: dict[str, int]) -> tuple[dict[str, Estimate], list[tuple[str | None, str]]]:
    """Estimate every node in ``order`` and check the limits.

    ``nodes`` maps names to validated graph nodes (``kind``, ``params``,
    ``inputs``).  Returns the estimates and the problems as ``(node name or
    None, message)``.
    """
    estimates: dict[str, Estimate] = {}
    for name in order:
        node = nodes[name]
        ins = {port: estimates.get(src) for port, src in node.inputs.items()}
        try:
            e = estimate_node(node.kind, node.params, ins)
        except Exception:  # an estimate is advice; a plugin's broken estimator must not block validation
            e = None
        if e is not None:
            estimates[name] = e
    problems: list[tuple[str | None, str]] = []
    room: int | None
    override = "set limits: {max_bytes: ...} in the graph or SBRDF_MAX_BYTES to change the limit"
    if "max_bytes" in limits:
        room, what = limits["max_bytes"], f"the limit max_bytes = {human(limits['max_bytes'])}"
    else:
        room = _free_disk(store)
        what = f"the {human(room)} free on the store's filesystem ({store})" if room is not None else ""
    if room is not None:
        pending = {n: e for n, e in estimates.items() if not _stored(store, n)}
        over = [n for n, e in pending.items() if e.bytes > room]
        for n in over:
            e = pending[n]
            problems.append((n, f"node {n!r} would write about {human(e.bytes)} ({e.how}), more than {what}; "
                                f"reduce its size or {override}"))
        total = sum(e.bytes for e in pending.values())
        if not over and total > room:
            biggest = max(pending, key=lambda n: pending[n].bytes)
            problems.append((biggest, f"the graph's nodes would write about {human(total)} together (node {biggest!r} "
                                      f"{human(pending[biggest].bytes)}), more than {what}; {override}"))
    memory = limits.get("max_memory") or _physical_memory()
    if memory:
        what = (f"the limit max_memory = {human(memory)}" if "max_memory" in limits
                else f"this machine's {human(memory)} of memory")
        for n, e in estimates.items():
            if e.peak is not None and e.peak > memory:
                problems.append((n, f"node {n!r} would hold about {human(e.peak)} in one task ({e.how}), more than "
                                    f"{what}; set limits: {{max_memory: ...}} or SBRDF_MAX_MEMORY to change the limit"))
    return estimates, problems
