"""Execute a validated graph with dask, node by node, chunk by chunk.

For each node, in dependency order:

1. open its inputs (complete artifacts only) and construct its plugin;
2. compute its *token*: ``tokenize`` of node kind, plugin name and version,
   parameters, the plugin's fingerprint and the input tokens;
3. if the artifact at ``<store>/<node>`` is complete with that token and
   passes the cheap integrity check (:func:`sbrdf_core.store.check_artifact`),
   skip it (cached); if it is damaged, drop what is damaged and recompute it
   (noted in the report); if it is partial with that token, resume; otherwise
   start fresh;
4. compute what the node kind's ``prepare`` asks for (lazy collections: a
   plugin's marker measurement, a codebook) on the run's scheduler with the
   node's progress bar, then ``build`` the lazy output with those results in
   ``ctx.prepared`` (``build`` itself never computes), and write only the
   chunks without a done marker, each in its own dask task
   (:func:`sbrdf_core.store.write_chunk`);
5. finalize and mark the artifact complete.

Execution is on dask's threaded scheduler by default, or on a
``dask.distributed`` cluster given its address.  A lost worker's tasks are
recomputed elsewhere by distributed; writes are idempotent, so results are
identical.

The whole run holds the store's lock (:class:`~sbrdf_core.store.StoreLock`):
a second run on the same store is refused at once, naming the holder, or
waits (``wait``).  A chunk of an input that fails its checksum stops the node
with a :class:`~sbrdf_core.store.ChunkError` naming artifact, array and chunk;
the chunk's done marker is dropped first, so a re-run recomputes it.

Process-wide tuning (glibc's malloc arenas, OpenCV's thread pool) is the
process owner's decision: the ``sbrdf`` command calls :func:`tune_process`
once at start-up, and a program that runs graphs calls it itself.  A dask
cluster's processes get the same settings from :data:`CLUSTER_CONFIG`
(docs/cluster.md).
What a run does is logged on ``sbrdf_core.runner`` (``sbrdf -v``).
"""

from __future__ import annotations

import getpass
import hashlib
import logging
import platform
import socket
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from . import __version__, compile_notice

# The public names of process tuning (the module is private).
from ._runtime import CLUSTER_CONFIG as CLUSTER_CONFIG
from ._runtime import WORKER_ENV as WORKER_ENV
from ._runtime import tune_process as tune_process
from .contracts import optional
from .errors import RunError, SbrdfError
from .extras import require
from .graph import Graph, Node
from .nodes.base import BuildContext, Output, Port
from .registry import Registry, default_registry
from .store import (
    ArrayLayout,
    ArtifactWriter,
    ChunkError,
    StoreLock,
    check_artifact,
    chunk_key,
    drop_chunks,
    inside_store,
    open_artifact,
    repair,
    write_chunk,
)
from .streaming import chunk_groups

if TYPE_CHECKING:
    from .plugin import PluginSpec

#: Chunk groups of a streamed node (:attr:`Output.stream`) in flight per worker
#: thread on a cluster: one running and one queued, so no thread waits for the runner.
STREAM_GROUPS_PER_THREAD = 2

#: Times a streamed node sends its shared data to the cluster again after a worker
#: died holding the only copy of it (the scheduler cannot recompute scattered data).
RESCATTERS = 3


class _ChunksLost(RunError):
    """A chunk task was cancelled or lost on the cluster: its chunks were not written."""

logger = logging.getLogger(__name__)

#: progress(node, done, total) is called after every chunk written.
ProgressFn = Callable[[str, int, int], None]


@dataclass
class NodeReport:
    """What running one node did."""

    node: str
    status: str  # cached | computed | resumed
    chunks_total: int = 0
    chunks_written: int = 0
    chunks_resumed: int = 0
    wall_s: float = 0.0
    url: str = ""
    token: str = ""
    #: What the run found and did beyond the status (a damaged cached artifact recomputed).
    notes: list[str] = field(default_factory=list)


@dataclass
class RunReport:
    graph: str
    nodes: list[NodeReport] = field(default_factory=list)

    def __getitem__(self, node: str) -> NodeReport:
        return next(r for r in self.nodes if r.node == node)

    def table(self) -> str:
        rows = [f"{'node':<14} {'status':<9} {'chunks':>13} {'wall_s':>8}  artifact"]
        for r in self.nodes:
            chunks = f"{r.chunks_written}/{r.chunks_total}" + (f" +{r.chunks_resumed}" if r.chunks_resumed else "")
            rows.append(f"{r.node:<14} {r.status:<9} {chunks:>13} {r.wall_s:>8.2f}  {r.url}")
            rows.extend(f"  ! {note}" for note in r.notes)
        return "\n".join(rows)


def node_token(node: Node, spec_version: str, inputs: dict, fingerprint: str) -> str:
    from dask.base import tokenize

    return tokenize(
        "sbrdf-node",
        node.kind.name,
        node.kind.output.version,
        node.plugin,
        spec_version,
        sorted(node.params.items(), key=lambda kv: kv[0]).__repr__(),
        sorted((port, art.token) for port, art in inputs.items()),
        fingerprint,
    )


class ChunkWrites:
    """A node's chunks still to write, and each one's write task, made when asked for.

    The tasks are made on demand so that a streamed node's runner holds a
    window of them, not one per chunk of the scan (2.4 KB each: 5 MB for
    Reflectance's 2050 chunks at 16 GB).

    Outputs are deliberately not optimized one by one: outputs that slice one
    kernel's result (images and valid of one pose read) must share its key, so
    the kernel runs once when their tasks are computed together.
    """

    def __init__(self, url: str, token: str, arrays: dict, done: dict):
        self.url, self.token, self.arrays = url, token, arrays
        # Write keys name the store too: two stores given identical artifacts (same token) on one cluster
        # must not share a write task, or only one of them would be written.
        self.key_id = f"{token}-{hashlib.sha1(url.encode()).hexdigest()[:8]}"
        self.numblocks = {name: arr.numblocks for name, arr in arrays.items()}
        self._starts = {name: [np.concatenate([[0], np.cumsum(c)]) for c in arr.chunks] for name, arr in arrays.items()}
        self.pending: list[tuple[str, tuple]] = []
        self.n_done = 0
        for name, arr in arrays.items():
            for index in np.ndindex(*arr.numblocks):
                if chunk_key(index) in done[name]:
                    self.n_done += 1
                else:
                    self.pending.append((name, index))

    def task(self, name: str, index: tuple):
        """The task that computes chunk ``index`` of output ``name`` and writes it."""
        from dask import delayed
        from dask.delayed import Delayed

        arr = self.arrays[name]
        block = Delayed((arr.name, *index), arr.__dask_graph__(), layer=arr.__dask_layers__()[0])
        region = tuple(slice(int(s[i]), int(s[i + 1])) for s, i in zip(self._starts[name], index))
        write = delayed(write_chunk, pure=True, name=f"write-{name}-{chunk_key(index)}-{self.key_id}")
        return write(block, self.url, name, self.token, index, region)


def _confine_outputs(graph: Graph, node: Node, spec: PluginSpec, params: dict) -> None:
    """The output-path rule again at run time (sbrdf_core.outputs): a graph built in Python skips validation."""
    from . import outputs

    anywhere, folders = graph.outside_store
    for p in spec.params or ():
        value = params.get(p.name)
        if p.extra.get("output") and isinstance(value, str):
            problem, _ = outputs.output_problem(value, graph.store, graph.nodes, anywhere, map(Path, folders))
            if problem:
                raise RunError(f"node {node.name!r}: parameter {p.name!r}: {problem}")


class Runner:
    """Runs graphs.

    Parameters
    ----------
    scheduler
        ``"threads"`` (default), ``"sync"``, ``"processes"``, a
        ``tcp://host:port`` address of a running ``dask.distributed``
        scheduler, or a ``distributed.Client``.
    num_workers
        Threads or processes for the local schedulers.
    progress
        ``True`` for a tqdm bar per node on stderr, ``False`` for none, or a
        callable ``progress(node, done, total)``.
    no_worker_timeout
        Seconds a distributed run waits with no workers at all before failing.
    wait
        When another run holds the store: ``False`` refuses at once, ``True``
        waits, a number waits that many seconds.
    """

    def __init__(
        self,
        registry: Registry | None = None,
        scheduler: Any = "threads",
        num_workers: int | None = None,
        progress: bool | ProgressFn = False,
        no_worker_timeout: float = 60.0,
        wait: bool | float = False,
    ):
        self.registry = registry or default_registry()
        self.scheduler = scheduler
        self.num_workers = num_workers
        self.progress = progress
        self.no_worker_timeout = no_worker_timeout
        self.wait = wait
        self._client = None

    # -- public -----------------------------------------------------------------

    def run(self, graph: Graph, only: Iterable[str] | None = None) -> RunReport:
        """Execute ``graph`` (or the nodes in ``only`` and what they need)."""
        report = RunReport(graph.name)
        wanted = self._closure(graph, only)
        try:
            with StoreLock(graph.store, self.wait, f"graph {graph.name!r}"):
                for node in graph.nodes.values():
                    if node.name in wanted:
                        report.nodes.append(self._run_node(graph, node))
        finally:
            if self._client is not None and isinstance(self.scheduler, str):
                self._client.close()
                self._client = None
        return report

    # -- one node -------------------------------------------------------------------

    def _run_node(self, graph: Graph, node: Node) -> NodeReport:
        try:
            return self._run_node_inner(graph, node)
        except ChunkError as e:
            # Whether the chunk was an input's or this node's own: drop its marker so a re-run rewrites it.
            inside_store(graph.store, e.url)
            drop_chunks(e.url, {e.array: set(e.keys) or None})
            raise RunError(f"node {node.name!r}: {e}. Its done marker was dropped: re-run the graph to "
                           f"recompute it") from None

    def _run_node_inner(self, graph: Graph, node: Node) -> NodeReport:
        t0 = time.perf_counter()
        url = inside_store(graph.store, graph.url(node.name))
        inputs = {port: open_artifact(inside_store(graph.store, graph.url(src)), kind=cast("Port", node.kind.port(port)).kinds)
                  for port, src in node.inputs.items()}
        spec: PluginSpec | None = None
        plugin = None
        plugin_params = node.params
        if node.kind.plugin_category is not None:
            spec = self.registry.get(node.kind.plugin_category, cast(str, node.plugin))
            own = {p.name for p in node.kind.params}
            plugin_params = {k: v for k, v in node.params.items() if k not in own}
            _confine_outputs(graph, node, spec, plugin_params)
            try:
                plugin = self.registry.load(spec)(**plugin_params)
                bind = optional(plugin, "bind")
                if bind is not None:  # plugins that look up other plugins (a model, a device)
                    bind(self.registry)
            except SbrdfError:
                raise
            except Exception as e:
                raise RunError(f"node {node.name!r}: plugin {node.plugin!r} rejected its parameters: {e}") from e
        ctx = BuildContext(node.name, dict(node.params), inputs, plugin, spec, self.registry, url)
        token = node_token(node, spec.version if spec else __version__, inputs, node.kind.fingerprint(ctx))
        writer = ArtifactWriter(url, node.kind.output, token, store=graph.store, node=node.name)
        state = writer.state()
        rep = NodeReport(node.name, "cached", url=url, token=token)
        if (state == "complete" or (state == "missing" and writer.fs.isdir(writer.root) and writer.fs.ls(writer.root))
                or (state == "stale" and writer.attrs() is None)):  # a zarr.json that does not parse
            damage = check_artifact(url)
            if not damage and state == "complete":
                rep.wall_s = time.perf_counter() - t0
                logger.info("node %r: cached, reusing %s (token %s)", node.name, url, token)
                return rep
            note = f"damaged: {'; '.join(damage.problems)}; recomputing {damage.plan()}"
            logger.warning("node %r: %s", node.name, note)
            rep.notes.append(note)
            if damage:
                repair(damage, graph.store, node.name)
        try:
            ctx.prepared = self._prepare(node, ctx)
            logger.info("node %r: building %s/%s", node.name, node.kind.name, node.plugin or "-")
            out = self._build(node, ctx)
        except SbrdfError:
            raise
        except Exception as e:
            raise RunError(f"node {node.name!r} ({node.kind.name}/{node.plugin}): {type(e).__name__}: {e}") from e
        arrays, layouts = _regularise(out)
        provenance = self._provenance(graph, node, spec, inputs, token)
        done = writer.prepare(layouts, {"provenance": provenance, **out.attrs})
        writes = ChunkWrites(url, token, arrays, done)
        n_done = writes.n_done
        rep.status = "resumed" if n_done else "computed"
        rep.chunks_total = sum(lay.nchunks for lay in layouts.values())
        rep.chunks_resumed = n_done
        logger.info("node %r: %s %d of %d chunks -> %s", node.name, "resuming" if n_done else "writing",
                    len(writes.pending), rep.chunks_total, url)
        rep.chunks_written = len(writes.pending)
        self._execute(node.name, token, writes, rep.chunks_total, n_done, sequential=out.sequential,
                      stream=out.stream)
        extra: dict[str, Any] = {}
        if out.finalize is not None:
            extra.update(out.finalize(open_artifact(url, require_complete=False)))
        rep.wall_s = time.perf_counter() - t0
        extra["run"] = {"wall_s": rep.wall_s, "chunks_written": rep.chunks_written, "chunks_resumed": n_done,
                        "finished": datetime.now(UTC).isoformat()}
        writer.mark_complete(layouts, extra)
        logger.info("node %r: %s in %.2f s (%d chunks written)", node.name, rep.status, rep.wall_s, rep.chunks_written)
        return rep

    def _rechunk_config(self) -> dict:
        import dask

        # dask picks p2p rechunking whenever a distributed client exists in the
        # process; p2p tasks only run on workers, so local runs must use tasks.
        method = dask.config.get("array.rechunk.method", None) if self._is_distributed() else "tasks"
        return {"array.rechunk.method": method}

    def _build(self, node: Node, ctx: BuildContext) -> Output:
        import dask

        with dask.config.set(self._rechunk_config()):
            return node.kind.build(ctx)

    def _prepare(self, node: Node, ctx: BuildContext) -> dict[str, Any]:
        """Compute what ``node.kind.prepare`` asks for, on this run's scheduler with the node's progress bar.

        A value is a dask collection or a list/tuple of them (each one a unit
        of progress per output key); the result keeps that shape.
        """
        import dask
        from dask.base import is_dask_collection

        with dask.config.set(self._rechunk_config()):
            wanted = node.kind.prepare(ctx)
        if not wanted:
            return {}
        flat: list[tuple[str, int | None, Any]] = []
        for name, value in wanted.items():
            if isinstance(value, (list, tuple)):
                flat.extend((name, i, v) for i, v in enumerate(value))
            else:
                flat.append((name, None, value))
        bad = [name for name, _, v in flat if not is_dask_collection(v)]
        if bad:
            raise RunError(f"node {node.name!r}: prepare must return dask collections; {sorted(set(bad))} are not")
        colls = [v for _, _, v in flat]
        t0 = time.perf_counter()
        logger.info("node %r: preparing %s (%d collections)", node.name, ", ".join(wanted), len(colls))
        results = self._compute(f"{node.name} prepare", colls)
        logger.info("node %r: prepared in %.2f s", node.name, time.perf_counter() - t0)
        prepared: dict[str, Any] = {}
        for (name, i, _), result in zip(flat, results):
            if i is None:
                prepared[name] = result
            else:
                prepared.setdefault(name, []).append(result)
        for name, value in wanted.items():
            if isinstance(value, tuple):
                prepared[name] = tuple(prepared[name])
            elif isinstance(value, list) and not value:
                prepared[name] = []
        return prepared

    def _compute(self, label: str, colls: list) -> list:
        """``dask.compute(*colls)`` on this run's scheduler, with a progress bar counting output keys."""
        import dask
        from dask.callbacks import Callback

        if not self._is_distributed():  # optimized first, so the keys counted are the keys computed
            colls = list(dask.optimize(*colls))
        keys = [set(_flatten(c.__dask_keys__())) for c in colls]
        total = sum(map(len, keys))
        bar = self._bar(label, total, 0, unit="key")
        try:
            if self._is_distributed():
                client = self._connect()
                from distributed import wait

                futures = client.compute(colls)
                pending = dict(zip(futures, map(len, keys)))
                while pending:
                    done = wait(list(pending), return_when="FIRST_COMPLETED").done
                    for f in done:
                        if f.status == "error":
                            client.cancel(list(pending))
                            f.result()  # raises the task's exception
                        bar(pending.pop(f))
                return [f.result() for f in futures]
            every = set().union(*keys)
            done = [0]

            def posttask(key, result, dsk, state, worker_id):
                if key in every:
                    done[0] += 1
                    bar(1)

            with Callback(posttask=posttask):
                results = dask.compute(*colls, scheduler=self.scheduler, num_workers=self.num_workers,
                                       optimize_graph=False)
            if done[0] < total:  # keys a scheduler renamed or ran without callbacks
                bar(total - done[0])
            return list(results)
        finally:
            bar(None)

    def _provenance(self, graph: Graph, node: Node, spec, inputs: dict, token: str) -> dict:
        return {
            "graph": {"name": graph.name, "file": graph.file, "sha256": graph.digest},
            "node": node.name,
            "node_kind": node.kind.name,
            "parameters": _jsonable(node.params),
            "plugin": None if spec is None else {
                "name": spec.name, "category": spec.category, "entry_point": spec.plugin,
                "distribution": spec.distribution, "version": spec.version,
            },
            "inputs": {port: {"url": a.url, "kind": a.kind, "token": a.token} for port, a in inputs.items()},
            "token": token,
            "sbrdf_version": __version__,
            "created": datetime.now(UTC).isoformat(),
            "host": socket.gethostname(),
            "user": _user(),
            "python": platform.python_version(),
        }

    # -- tasks ----------------------------------------------------------------------

    def _execute(self, node: str, token: str, writes: ChunkWrites, total: int, already: int,
                 sequential: bool = False, stream: int = 0) -> None:
        if not writes.pending:
            return
        bar = self._bar(node, total, already)
        try:
            if sequential:
                # Hardware: in this process, in order of the first (pose) axis; the
                # chunks of one pose are computed together so the pose is taken once.
                by_pose: dict[int, list] = {}
                for name, index in writes.pending:
                    by_pose.setdefault(index[0] if index else 0, []).append((writes.task(name, index), [(name, index)]))
                for pose in sorted(by_pose):
                    self._execute_local(by_pose[pose], bar, scheduler="sync")
                return
            # (task, chunks it writes): a fused task per chunk group when streamed.
            every = ((writes.task(name, index), [(name, index)]) for name, index in writes.pending)
            if not self._is_distributed():
                units = chunk_groups(node, token, writes, stream) if stream else every
                self._execute_local(list(units), bar, self.scheduler)
            elif stream:
                self._execute_streamed(node, token, writes, stream, bar)
            else:
                self._execute_distributed(node, every, bar, window=None, written=set())
        except SbrdfError:
            raise
        except Exception as e:
            raise RunError(f"node {node!r} failed: {type(e).__name__}: {e}") from e
        finally:
            bar(None)

    def _execute_local(self, units: list, bar, scheduler) -> None:
        import dask
        from dask.callbacks import Callback

        chunks = {t.key: len(n) for t, n in units}

        def posttask(key, result, dsk, state, worker_id):
            if key in chunks:
                bar(chunks[key])

        with Callback(posttask=posttask):
            dask.compute(*[t for t, _ in units], scheduler=scheduler, num_workers=self.num_workers,
                         optimize_graph=False)

    def _is_distributed(self) -> bool:
        s = self.scheduler
        return not isinstance(s, str) or "://" in s

    def _connect(self):
        if self._client is None:
            if isinstance(self.scheduler, str):
                distributed = require("distributed", feature=f"scheduler {self.scheduler!r} (a dask.distributed cluster)")
                logger.info("connecting to the dask scheduler at %s", self.scheduler)
                self._client = distributed.Client(self.scheduler)
            else:
                self._client = self.scheduler
        return self._client

    def _execute_streamed(self, node: str, token: str, writes: ChunkWrites, axes: int, bar) -> None:
        """Chunk groups on the cluster, each shared value scattered once to every worker.

        A worker that joined after the scatter holds no copy, so one that dies
        may take the last copy with it; the scheduler cannot recompute
        scattered data and cancels the groups that need it. Those groups' chunks
        were not written: the rest are sent again, with the data scattered anew.
        """
        client = self._connect()
        for attempt in range(RESCATTERS + 1):
            scattered: dict = {}

            def data(key, value, scattered=scattered):
                # Each shared value sent to the cluster once, not with every group.
                if key not in scattered:
                    scattered[key] = client.scatter(value, hash=False, broadcast=True)
                return scattered[key]

            written: set = set()
            try:
                units = chunk_groups(node, token, writes, axes, data, attempt)
                self._execute_distributed(node, units, bar, window=STREAM_GROUPS_PER_THREAD, written=written)
                return
            except _ChunksLost as e:
                if attempt == RESCATTERS or not sum(client.nthreads().values()):
                    raise
                logger.warning("%s; scattering its data again (%d of %d)", e, attempt + 1, RESCATTERS)
                writes.pending = [c for c in writes.pending if c not in written]
            finally:
                client.cancel(list(scattered.values()))

    def _execute_distributed(self, node: str, units: Iterator, bar, window: int | None, written: set) -> None:
        """Compute ``(task, chunks)`` units on the cluster: all at once (``window=None``), or
        at most ``window`` per worker thread in flight, submitted in order as others finish.
        The chunks of every unit that finished are added to ``written``."""
        from distributed import as_completed

        client = self._connect()
        pending: dict = {}  # future -> chunks it writes
        seq = as_completed(with_results=False)
        submitted, threads = 0, sum(client.nthreads().values())

        def refill():
            nonlocal submitted
            if window is None:
                batch = list(units)
                futures = client.compute([t for t, _ in batch]) if batch else []
                pending.update(zip(futures, (n for _, n in batch)))
                seq.update(futures)
                return
            while len(pending) < window * max(1, threads) and (unit := next(units, None)) is not None:
                # Earlier groups first, whatever a worker has queued.
                future = client.compute(unit[0], priority=-submitted)
                submitted += 1
                pending[future] = unit[1]
                seq.add(future)

        refill()
        no_workers_since, checked = None, 0.0
        while pending:
            batch = seq.next_batch(block=False)
            for f in batch:
                n = pending.pop(f)
                if f.status == "error":
                    client.cancel(list(pending))
                    exc = f.exception()
                    if isinstance(exc, ChunkError):
                        raise exc
                    raise RunError(f"node {node!r}: a chunk task failed on the cluster: {type(exc).__name__}: {exc}")
                if f.status != "finished":  # cancelled or lost: its chunks were not written
                    client.cancel(list(pending))
                    raise _ChunksLost(f"node {node!r}: a chunk task was {f.status} on the cluster; "
                                      f"{len(pending) + 1} tasks unfinished (re-run to resume)")
                written.update(n)
                bar(len(n))
            if batch:
                refill()
            elif time.monotonic() - checked > 1.0:  # an RPC: not on every idle poll
                checked = time.monotonic()
                threads = sum(client.nthreads().values())
                if threads:
                    no_workers_since = None
                else:
                    no_workers_since = no_workers_since or checked
                    if checked - no_workers_since > self.no_worker_timeout:
                        client.cancel(list(pending))
                        raise RunError(
                            f"node {node!r}: no dask workers left on {client.scheduler.address} for "
                            f"{self.no_worker_timeout:.0f} s; {len(pending)} chunks unwritten (re-run to resume)"
                        )
            else:
                time.sleep(0.05)

    def _bar(self, node: str, total: int, already: int, unit: str = "chunk"):
        progress = self.progress
        if callable(progress):
            count = [already]

            def cb(n):
                if n:
                    count[0] += n
                    progress(node, count[0], total)

            return cb
        if not self.progress:
            return lambda n: None
        from tqdm import tqdm

        t = tqdm(total=total, initial=already, desc=f"{node:<12}", unit=unit, file=sys.stderr, leave=True)

        def note(text: str | None) -> None:
            t.set_postfix_str(text or "", refresh=True)
            if text is None:  # a compilation's seconds are no chunk's: the rate (and the estimate) start after it
                t.last_print_t = time.time()

        unwatch = compile_notice.watch(note)

        def update(n):
            if n is None:
                unwatch()
                t.close()
            else:
                t.update(n)

        return update

    @staticmethod
    def _closure(graph: Graph, only: Iterable[str] | None) -> set[str]:
        if not only:
            return set(graph.nodes)
        wanted: set[str] = set()
        stack = list(only)
        while stack:
            n = stack.pop()
            if n not in graph.nodes:
                raise RunError(f"no node {n!r} in graph {graph.name!r}; nodes: {', '.join(graph.nodes)}")
            if n not in wanted:
                wanted.add(n)
                stack.extend(graph.nodes[n].inputs.values())
        return wanted


def _regularise(out: Output) -> tuple[dict, dict[str, ArrayLayout]]:
    """Rechunk every output to its stored chunking so one task writes whole chunks."""
    arrays, layouts = {}, {}
    for name, arr in out.arrays.items():
        chunks = out.chunks.get(name) or tuple(c[0] if c else 1 for c in arr.chunks)
        chunks = tuple(max(1, min(c, s)) if s else 1 for c, s in zip(chunks, arr.shape))
        if any(c and (any(x != k for x in c[:-1]) or c[-1] > k) for c, k in zip(arr.chunks, chunks)):
            arr = arr.rechunk(chunks)
        fill = float("nan") if np.dtype(arr.dtype).kind == "f" else 0
        inner = out.inner_chunks.get(name)
        if inner is not None:  # a shard holds whole inner chunks: round a whole-axis chunk up
            inner = tuple(max(1, min(i, c)) for i, c in zip(inner, chunks))
            if any(c % i and c < s for c, i, s in zip(chunks, inner, arr.shape)):
                raise RunError(f"output {name!r}: chunks {chunks} are not multiples of inner chunks {inner}")
            chunks = tuple(-(-c // i) * i for c, i in zip(chunks, inner))
        arrays[name] = arr
        layouts[name] = ArrayLayout(tuple(arr.shape), chunks, np.dtype(arr.dtype).name, fill, inner)
    return arrays, layouts


def _flatten(keys) -> Iterator:
    """The keys of a collection's nested ``__dask_keys__()`` lists."""
    for k in keys:
        if isinstance(k, list):
            yield from _flatten(k)
        else:
            yield k


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.generic,)):
        return value.item()
    return value


def _user() -> str:
    try:
        return getpass.getuser()
    except Exception:
        return ""


def run_graph(source, store: str | None = None, **runner_kwargs) -> RunReport:
    """Load, validate and run a graph file: the one-call API."""
    from .graph import load_graph

    runner = Runner(**runner_kwargs)
    return runner.run(load_graph(source, runner.registry, store=store))
