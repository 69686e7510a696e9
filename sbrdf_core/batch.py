"""Batches of scans: one graph, one store per scan, on one scheduler or cluster.

A batch is a list of :class:`Scan` (variable values, and optionally a store of
its own), read from a CSV file (:func:`scans_from_csv`: the header names the
graph's variables, one row per scan, plus an optional ``store`` column) or
found in a folder of capture folders (:func:`scans_from_dir`: each subfolder
holding a capture manifest is a scan, ``path`` = that folder, ``scan`` = its
name).  :func:`run_batch` validates every scan first (an invalid one is
reported and skipped), then runs each one's graph into ``<root>/<scan>`` (the
*root* is the graph's store, or ``--store``) unless the CSV names its store.
A scan that fails is reported and the others go on.  Every scan's nodes are
cached as in a single run, so re-running a batch recomputes only what is
missing; ``<root>/batch.json`` records each scan's outcome, node times and fit
errors.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import os
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from .errors import GraphError, SbrdfError
from .graph import VARIABLE_NAME, Graph, declared_variables, graph_store, load_graph
from .input_files import read_text
from .registry import Registry, default_registry
from .store import NODE_NAME

logger = logging.getLogger(__name__)

#: The file a capture folder's manifest is in: a subfolder of ``--batch DIR`` holding it is a scan.
CAPTURE_MANIFEST = "capture.json"
#: The batch summary, written to the batch's root store folder.
SUMMARY = "batch.json"
#: A CSV column that is not a variable: the scan's store.
STORE_COLUMN = "store"


@dataclass
class Scan:
    """One scan of a batch: its name, the variable values it gives the graph, and its own store (if any)."""

    name: str
    variables: dict[str, str]
    store: str | None = None
    #: Where it was declared (``scans.csv:4``), for messages.
    where: str = ""
    #: The variables are offered, not demanded: those the graph does not declare are left out (``--batch DIR``).
    offered: bool = False


@dataclass
class ScanResult:
    """What running one scan did.  ``status``: computed (something was written), cached (nothing was),
    failed (the run stopped with an error), invalid (the graph did not validate for this scan)."""

    scan: str
    store: str
    status: str = "pending"
    error: str = ""
    wall_s: float = 0.0
    #: node -> (status, wall seconds)
    nodes: dict[str, tuple[str, float]] = field(default_factory=dict)
    #: Fit node -> {rms_mean, rms_max, rms_holdout_mean, texels_flagged_any} from its ParamMaps' summary.
    fits: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status in ("computed", "cached")


@dataclass
class BatchReport:
    graph: str
    root: str
    scans: list[ScanResult] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def failed(self) -> list[ScanResult]:
        return [s for s in self.scans if not s.ok]

    def table(self) -> str:
        """One row per scan: status, wall time, each node's time, and the first Fit node's RMS and held-out error."""
        nodes: list[str] = []
        for s in self.scans:
            nodes += [n for n in s.nodes if n not in nodes]
        fit = next((f for s in self.scans for f in s.fits), None)
        width = max([len("scan")] + [len(s.scan) for s in self.scans])
        head = f"{'scan':<{width}} {'status':<9} {'wall_s':>8}" + "".join(f" {n[:10]:>10}" for n in nodes)
        if fit:
            head += f" {'rms':>10} {'held_out':>10}"
        rows = [head, "-" * len(head)]
        fmt = lambda x: f"{x:.4g}" if isinstance(x, (int, float)) else "-"  # noqa: E731
        for s in self.scans:
            row = f"{s.scan:<{width}} {s.status:<9} {s.wall_s:>8.2f}"
            row += "".join(f" {s.nodes[n][1]:>10.2f}" if n in s.nodes else f" {'-':>10}" for n in nodes)
            if fit:
                f = s.fits.get(fit, {})
                row += f" {fmt(f.get('rms_mean')):>10} {fmt(f.get('rms_holdout_mean')):>10}"
            rows.append(row)
            if s.error:
                rows.extend(f"  ! {line}" for line in s.error.splitlines())
        done = sum(s.ok for s in self.scans)
        rows.append(f"{done} of {len(self.scans)} scans done, {len(self.scans) - done} failed, in {self.wall_s:.1f} s"
                    + (f"; node times are wall seconds; rms and held_out from node {fit!r}" if fit else ""))
        return "\n".join(rows)

    def to_json(self) -> dict:
        return {"graph": self.graph, "root": self.root, "wall_s": self.wall_s,
                "finished": datetime.now(UTC).isoformat(),
                "scans": [{**asdict(s), "nodes": {n: {"status": st, "wall_s": w} for n, (st, w) in s.nodes.items()}}
                          for s in self.scans]}


# -- where the scans come from -------------------------------------------------------


def scans_from_csv(path: str | os.PathLike) -> list[Scan]:
    """Scans from a CSV file: the header names variables (and ``store``), one row per scan.

    A scan's name is its ``scan`` column, else ``row<N>``; a ``store`` that is a
    relative path is relative to the CSV file's folder.  Duplicate names or
    stores, ragged rows and an empty file are errors naming the line.
    """
    path = Path(path)
    try:
        raw = list(csv.reader(io.StringIO(read_text(path, encoding="utf-8-sig"), newline="")))
    except (OSError, UnicodeDecodeError) as e:
        raise SbrdfError(f"{path}: cannot read the batch CSV: {e}") from None
    rows = [(i + 1, r) for i, r in enumerate(raw) if any(c.strip() for c in r)]
    if len(rows) < 2:
        raise SbrdfError(f"{path}: a batch CSV needs a header (variable names, e.g. scan,path) and one row per scan")
    (first, names), body = rows[0], rows[1:]
    header = [h.strip() for h in names]
    for h in header:
        if not VARIABLE_NAME.fullmatch(h):
            raise SbrdfError(f"{path}:{first}: column {h!r} is not a variable name (nor {STORE_COLUMN!r})")
    if len(set(header)) != len(header):
        raise SbrdfError(f"{path}:{first}: a column is named twice: {', '.join(header)}")
    scans: list[Scan] = []
    for line, row in body:
        if len(row) != len(header):
            raise SbrdfError(f"{path}:{line}: {len(row)} values for {len(header)} columns ({', '.join(header)})")
        values = {h: v.strip() for h, v in zip(header, row)}
        store = values.pop(STORE_COLUMN, None) or None
        if store and "://" not in store and not Path(store).is_absolute():
            store = str((path.resolve().parent / store).resolve())
        scans.append(Scan(values.get("scan") or f"row{line}", values, store, f"{path}:{line}"))
    _check_unique(scans, str(path))
    return scans


def scans_from_dir(folder: str | os.PathLike) -> list[Scan]:
    """Scans from a folder of capture folders: each subfolder holding a capture manifest (``capture.json``),
    in name order, with variables ``scan`` (the subfolder's name) and ``path`` (the subfolder)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SbrdfError(f"{folder}: not a folder")
    scans = [Scan(d.name, {"scan": d.name, "path": str(d.resolve())}, None, str(d), offered=True)
             for d in sorted(folder.iterdir()) if d.is_dir() and (d / CAPTURE_MANIFEST).is_file()]
    if not scans:
        raise SbrdfError(f"{folder}: no capture folders here (subfolders holding {CAPTURE_MANIFEST})")
    return scans


def scans_from(source: str | os.PathLike) -> list[Scan]:
    """:func:`scans_from_dir` for a folder, :func:`scans_from_csv` otherwise."""
    return scans_from_dir(source) if Path(source).is_dir() else scans_from_csv(source)


def _check_unique(scans: list[Scan], where: str) -> None:
    seen: dict[str, Scan] = {}
    for s in scans:
        if s.name in seen:
            raise SbrdfError(f"{s.where}: scan {s.name!r} appears twice (also {seen[s.name].where}); "
                             f"each scan needs a store of its own")
        seen[s.name] = s
    stores: dict[str, Scan] = {}
    for s in scans:
        if s.store and s.store in stores:
            raise SbrdfError(f"{s.where}: store {s.store!r} is also scan {stores[s.store].name!r}'s")
        if s.store:
            stores[s.store] = s


# -- running ---------------------------------------------------------------------------


def run_batch(
    graph: str | os.PathLike,
    scans: Iterable[Scan],
    registry: Registry | None = None,
    scheduler: Any = "threads",
    num_workers: int | None = None,
    progress: bool = False,
    variables: Mapping[str, Any] | None = None,
    overrides: Any = None,
    store: str | None = None,
    only: Iterable[str] | None = None,
    concurrent: int = 1,
    wait: bool | float = False,
    echo: Callable[[str], None] | None = print,
) -> BatchReport:
    """Run ``graph`` once per scan, each into its own store, and write the summary to ``<root>/batch.json``.

    ``variables`` (``--var``) are common to every scan (a scan's own values win);
    ``overrides`` (``--set``) apply to every scan.  ``scheduler`` is a local
    scheduler's name, a ``tcp://`` address (one client is shared by the scans)
    or a ``distributed.Client``.  ``concurrent`` scans run at once (threads of
    this process, each submitting its own graphs), on a local scheduler or on
    one cluster: every dask key a node makes names its artifact (a hash of its
    URL, ``BuildContext.key``; write keys hash the store URL), so scans in
    flight together never share a key.  On a cluster, a few scans in flight keep
    the workers busy while one scan's client builds, writes attributes or
    finalizes.  Per-node progress bars are shown only when one scan runs at a
    time.  ``echo`` gets one line per scan start and finish.
    """
    from .runner import Runner

    registry = registry or default_registry()
    scans = list(scans)
    _check_unique(scans, "batch")
    common = dict(variables or {})
    root = store if store is not None else graph_store(graph, common, overrides)
    root = root.rstrip("/")
    say = echo or (lambda line: None)
    lock = threading.Lock()
    report = BatchReport(str(graph), root)
    t0 = time.perf_counter()

    declared = declared_variables(graph)
    graphs: dict[str, Graph] = {}
    for scan in scans:
        # A folder batch offers scan and path, and a CSV's scan column names the scan: a graph uses those it
        # declares; any other CSV column must be one of its variables.
        own = {k: v for k, v in scan.variables.items() if k in declared or not (scan.offered or k == "scan")}
        values = {**common, **own}
        scan_store = scan.store or f"{root}/{scan.name}"
        result = ScanResult(scan.name, scan_store)
        report.scans.append(result)
        if not NODE_NAME.fullmatch(scan.name) and not scan.store:
            result.status, result.error = "invalid", (f"{scan.where}: scan name {scan.name!r} cannot name a store "
                                                      f"folder (letters, digits, '_', '-'); give it a store column")
            continue
        try:
            graphs[scan.name] = load_graph(graph, registry, store=scan_store, variables=values, overrides=overrides)
        except GraphError as e:
            problems = "\n".join(str(p) for p in e.problems)
            result.status, result.error = "invalid", f"{scan.where}: {problems}" if scan.where else problems

    client = None
    if isinstance(scheduler, str) and "://" in scheduler:
        from .extras import require

        distributed = require("distributed", feature=f"scheduler {scheduler!r} (a dask.distributed cluster)")
        client = distributed.Client(scheduler)
        shared: Any = client
    else:
        shared = scheduler
    n = len(scans)
    index = {s.scan: i + 1 for i, s in enumerate(report.scans)}

    def one(result: ScanResult) -> None:
        g = graphs[result.scan]
        with lock:
            say(f"[{index[result.scan]}/{n}] {result.scan}: started -> {result.store}")
        ts = time.perf_counter()
        try:
            runner = Runner(registry, scheduler=shared, num_workers=num_workers,
                            progress=progress and concurrent <= 1, wait=wait)
            rep = runner.run(g, only=only)
            result.nodes = {r.node: (r.status, round(r.wall_s, 3)) for r in rep.nodes}
            result.status = "cached" if all(r.status == "cached" for r in rep.nodes) else "computed"
            result.fits = _fits(rep)
        except KeyboardInterrupt:
            raise
        except Exception as e:  # noqa: BLE001  (a failed scan is reported; the others go on)
            result.status = "failed"
            result.error = str(e) if isinstance(e, SbrdfError) else f"{type(e).__name__}: {e}"
        result.wall_s = time.perf_counter() - ts
        with lock:
            say(f"[{index[result.scan]}/{n}] {result.scan}: {_finish_line(result)}")

    try:
        for result in report.scans:
            if result.status == "invalid":
                say(f"[{index[result.scan]}/{n}] {result.scan}: invalid, skipped: {result.error.splitlines()[0]}")
        todo = [r for r in report.scans if r.scan in graphs]
        if concurrent <= 1:
            for result in todo:
                one(result)
        else:
            with ThreadPoolExecutor(max_workers=concurrent, thread_name_prefix="sbrdf-batch") as pool:
                list(pool.map(one, todo))
    finally:
        if client is not None:
            client.close()
    report.wall_s = time.perf_counter() - t0
    _write_summary(report)
    return report


def _finish_line(r: ScanResult) -> str:
    if r.status == "failed":
        return f"FAILED after {r.wall_s:.1f} s: {r.error.splitlines()[0] if r.error else ''}"
    fit = next(iter(r.fits.values()), {})
    errs = ", ".join(f"{label} {fit[k]:.4g}" for k, label in (("rms_mean", "rms"), ("rms_holdout_mean", "held-out"))
                     if isinstance(fit.get(k), (int, float)))
    return f"{r.status} in {r.wall_s:.1f} s" + (f" ({errs})" if errs else "")


def _fits(rep) -> dict[str, dict[str, Any]]:
    """Fit errors from the summary attributes of the run's ParamMaps artifacts."""
    from .store import open_artifact

    out = {}
    for r in rep.nodes:
        try:
            art = open_artifact(r.url)
        except SbrdfError:
            continue
        summary = art.attrs.get("summary") if art.kind == "ParamMaps" else None
        if isinstance(summary, dict):
            out[r.node] = {k: summary.get(k) for k in ("rms_mean", "rms_max", "rms_holdout_mean", "texels_flagged_any")
                           if k in summary}
    return out


def _write_summary(report: BatchReport) -> None:
    import fsspec

    fs, root = fsspec.core.url_to_fs(report.root)
    fs.makedirs(root, exist_ok=True)
    with fs.open(root.rstrip("/") + "/" + SUMMARY, "w") as f:
        json.dump(report.to_json(), f, indent=1, default=str)
