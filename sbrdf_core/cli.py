"""``sbrdf``: run, validate, list plugins, inspect artifacts.

    sbrdf run GRAPH [--scheduler tcp://host:8786] [--store URL] [--only NODE ...] [--wait] [--wait-timeout S]
              [--var NAME=VALUE ...] [--set NODE.params.KEY=VALUE ...] [--batch scans.csv|DIR [--concurrent N]]
    sbrdf verify STORE [--repair] [--wait] [--wait-timeout S]
    sbrdf validate GRAPH
    sbrdf plugins [--category fitter]
    sbrdf info STORE_OR_ARTIFACT
    sbrdf bench [STAGE ...] [--quick | --full] [--no-images] [--log FILE]

Plugins add commands (``sbrdf_commands``): the viewer plugin's ``sbrdf view``
and ``sbrdf plot``, for instance; ``sbrdf --help`` lists those installed.
``-p MODULE`` registers an extra plugin module (pytest's ``-p``), and
``-p no:NAME`` disables an installed plugin by entry-point name; ``-v`` / ``-vv``
log what runs (INFO / DEBUG of sbrdf's loggers).
"""

from __future__ import annotations

import argparse
import functools
import json
import logging
import os
import sys
import time
from pathlib import Path
from typing import Any

from ._runtime import tune_process
from .errors import PluginError, SbrdfError

logger = logging.getLogger(__name__)


def _registry(args):
    """The registry of the ``-p`` plugin set: built once per invocation (the plugin subcommands need it first)."""
    return _registry_for(tuple(args.plugin))


@functools.lru_cache(maxsize=4)
def _registry_for(plugins: tuple[str, ...]):
    from .registry import Registry

    disabled = [p[3:] for p in plugins if p.startswith("no:")]
    extra = [p for p in plugins if not p.startswith("no:")]
    try:
        return Registry(disabled=disabled, extra=extra)
    except ImportError as e:  # a -p MODULE that does not import: the user's input, so no traceback
        module = next((m for m in extra if e.name and (m == e.name or m.startswith(e.name + "."))), e.name or "?")
        raise PluginError(f"-p {module}: the plugin module cannot be imported: {e}") from None


def cmd_validate(args) -> int:
    from .graph import load_graph

    g = load_graph(args.graph, _registry(args), store=_store_arg(args.store))
    print(f"{args.graph}: graph {g.name!r} is valid: {len(g.nodes)} nodes -> {g.store}")
    for n in g.nodes.values():
        ins = ", ".join(f"{p}<-{s}" for p, s in n.inputs.items())
        print(f"  {n.name:<14} {n.kind.name:<12} {n.plugin or '-':<16} {ins}")
    return 0


def cmd_run(args) -> int:
    from .graph import load_graph
    from .runner import Runner

    reg = _registry(args)
    variables = _variables_arg(args.var)
    if args.batch:
        return _run_batch(args, reg, variables)
    g = load_graph(args.graph, reg, store=_store_arg(args.store), variables=variables, overrides=args.set)
    runner = Runner(reg, scheduler=args.scheduler, num_workers=args.workers, progress=not args.quiet, wait=_wait(args))
    t0 = time.perf_counter()
    report = runner.run(g, only=args.only)
    print(report.table())
    print(f"graph {g.name!r} done in {time.perf_counter() - t0:.1f} s; artifacts in {g.store}")
    return 0


def _variables_arg(items: list[str]) -> dict[str, str]:
    """``--var NAME=VALUE`` options as a mapping (values as text: the graph's declarations type them)."""
    out = {}
    for item in items:
        name, eq, value = item.partition("=")
        if not eq or not name.strip():
            raise SbrdfError(f"--var {item}: a variable is given as NAME=VALUE (e.g. --var scan=tile-07)")
        out[name.strip()] = value
    return out


def _run_batch(args, reg, variables: dict[str, str]) -> int:
    """``sbrdf run GRAPH --batch scans.csv|DIR``: one store per scan; exit status 1 if a scan failed."""
    from .batch import SUMMARY, run_batch, scans_from

    report = run_batch(args.graph, scans_from(args.batch), reg, scheduler=args.scheduler, num_workers=args.workers,
                       progress=not args.quiet, variables=variables, overrides=args.set,
                       store=_store_arg(args.store), only=args.only, concurrent=args.concurrent, wait=_wait(args))
    print(report.table())
    print(f"batch summary in {report.root}/{SUMMARY}")
    return 1 if report.failed else 0


def cmd_verify(args) -> int:
    """Read every chunk of every artifact; say what is damaged and what a re-run recomputes.

    Exit status 1 when anything is damaged (0 when all is sound).  With
    ``--repair`` the damage is turned into work for the next run (done markers
    of bad chunks dropped, broken artifacts removed, links and FIFOs inside
    artifacts removed as themselves); without it nothing is written, and a
    store this process cannot write is verified read-only.
    """
    from .errors import ArtifactError
    from .store import ARTIFACT_MARKER, StoreLock, artifact_dirs, check_artifact, disk_errors, repair, stray_entries

    urls, unproven = artifact_dirs(args.store)
    strays = stray_entries(args.store)
    if not urls and not unproven and not strays:
        raise SbrdfError(f"{args.store}: no sbrdf artifacts here")
    damaged = len(unproven) + len(strays)
    lock = StoreLock(args.store, _wait(args), "sbrdf verify", read_only=not args.repair)
    with lock:
        if lock.note:
            print(lock.note)
        for url in unproven:
            print(f"{url}  ?  DAMAGED\n    holds zarr arrays but no group zarr.json and no {ARTIFACT_MARKER}: nothing "
                  f"proves it is an artifact, so a run refuses to delete it; move it away, then a re-run recomputes it")
        for url, why, removable in strays:
            print(f"{url}  ?  DAMAGED\n    {why}")
            if removable and args.repair:
                os.unlink(url if "://" not in url else url.split("://", 1)[1])
                print("    repaired: the link was removed (not what it points to); the next run computes the node")
            elif removable:
                print(f"    `sbrdf verify --repair {args.store}` removes the link (not what it points to)")
            else:
                print("    not sbrdf's to delete: move it away, then a re-run computes the node")
        for url in urls:
            node = url.rstrip("/").rsplit("/", 1)[-1]
            d = check_artifact(url, full=True)
            kind = d.kind or "?"
            if not d:
                state = "ok" if d.complete else "incomplete (an interrupted run): a re-run resumes it"
                print(f"{url}  {kind}  {state}" + "".join(f"\n    {n}" for n in d.notes))
                continue
            damaged += 1
            print(f"{url}  {kind}  DAMAGED" + ("" if d.complete else " (and incomplete: an interrupted run)"))
            for p in d.problems:
                print(f"    {p}")
            if args.repair:
                try:
                    with disk_errors(args.store, f"the repair of artifact {url}"):
                        repair(d, args.store, node)
                except ArtifactError as e:
                    print(f"    NOT repaired: {e}")
                    continue
                print(f"    repaired: the next run recomputes {d.plan()} of node {node!r}")
            elif d.deep:
                print(f"    a re-run does not see this (it reads no chunk of a cached artifact): "
                      f"`sbrdf verify --repair {args.store}` marks it, then a re-run recomputes {d.plan()} of node {node!r}")
            else:
                print(f"    a re-run recomputes {d.plan()} of node {node!r}")
    print(f"{args.store}: {len(urls) + len(unproven) + len(strays)} artifacts, {damaged} damaged"
          + ("; nodes downstream of a recomputed one stay cached (same inputs, same token)" if damaged else ""))
    return 1 if damaged else 0


def cmd_plugins(args) -> int:
    from .params import format_table

    reg = _registry(args)
    print("node kinds:")
    for name, kind in reg.node_kinds.items():
        ins = ", ".join(f"{p.name}: {p.kind_names}" for p in kind.inputs) or "-"
        plug = f"plugin: {kind.plugin_category}" if kind.plugin_category else "no plugin"
        print(f"  {name:<12} ({ins}) -> {kind.output.kind}; {plug}")
        if kind.params:
            print(format_table(kind.params))
    for category, specs in reg.specs.items():
        if args.category and category != args.category:
            continue
        if not specs and not args.category:
            continue
        print(f"\n{category}:")
        for name in sorted(specs):
            try:  # a spec without its parameters names them on the implementation, which this imports
                spec = reg.get(category, name)
            except PluginError as e:
                print(f"  {name}  unavailable: {e}", file=sys.stderr)
                continue
            src = f"{spec.distribution} {spec.version}".strip() or spec.plugin
            print(f"  {spec.name}  [{src}]  {spec.summary}")
            print(format_table(spec.params))
    for name, err in reg.failed.items():
        print(f"\nfailed to load plugin {name!r}: {err}", file=sys.stderr)
    return 0


def _store_arg(store: str | None) -> str | None:
    """``--store``: a local path is relative to the current directory (a graph's own ``store:`` is relative to the
    graph file); URLs pass through."""
    if store is None or "://" in store:
        return store
    return str(Path(store).expanduser().resolve())


def cmd_info(args) -> int:
    """Describe every artifact of a store (or one artifact), then the fit table of its ParamMaps.

    Zarr groups that are not sbrdf artifacts (a plugin's side store, such as the
    ``factors:`` store of the ``nd`` and ``svd`` fitters in graphs/separable.yaml)
    are described as such: what they hold and which artifact names them, never
    an error.
    """
    import fsspec

    from .errors import ArtifactError
    from .store import open_artifact

    fs, root = fsspec.core.url_to_fs(args.store)
    if not fs.exists(root):
        raise SbrdfError(f"{args.store}: no such store or artifact")
    if fs.exists(root.rstrip("/") + "/zarr.json"):
        urls = [args.store]
    else:
        urls = sorted(args.store.rstrip("/") + "/" + p.rstrip("/").rsplit("/", 1)[-1]
                      for p in fs.ls(root, detail=False) if fs.exists(p.rstrip("/") + "/zarr.json"))
        if not urls:
            raise SbrdfError(f"{args.store}: no sbrdf artifacts here")
    opened: list[tuple[str, Any, str | None]] = []
    for url in urls:
        try:
            opened.append((url, open_artifact(url, require_complete=False), None))
        except ArtifactError as e:
            opened.append((url, None, str(e)))
    fits = []
    for url, art, err in opened:
        if art is None:
            _describe_other_zarr(url, err, [(u, a) for u, a, _ in opened if a is not None])
            continue
        _describe_artifact(url, art)
        if art.kind == "ParamMaps" and art.complete:
            fits.append((url, art))
    if fits:
        print(fit_table(fits))
    others = sum(art is None for _, art, _ in opened)
    if others and len(opened) > 1:
        print(f"{args.store}: {len(opened) - others} sbrdf artifacts and {others} other zarr store"
              f"{'s' if others != 1 else ''} (described above as not sbrdf artifacts)")
    return 0


def _describe_artifact(url: str, art) -> None:
    import zarr

    prov = art.provenance
    plugin = prov.get("plugin") or {}
    print(f"{url}\n  {art.kind} v{art.version}  {'complete' if art.complete else 'INCOMPLETE'}  "
          f"{art.nbytes_stored() / 2**20:.2f} MiB stored  token {art.token}")
    print(f"  node {prov.get('node')!r} ({prov.get('node_kind')}) of graph {prov.get('graph', {}).get('name')!r}"
          + (f", plugin {plugin.get('name')} {plugin.get('distribution', '')} {plugin.get('version', '')}" if plugin else ""))
    print(f"  parameters: {json.dumps(prov.get('parameters', {}))}")
    for port, i in prov.get("inputs", {}).items():
        print(f"  input {port}: {i['kind']} {i['url']} (token {i['token']})")
    from .errors import ArtifactError

    declared = art.attrs.get("layout") or {}
    for name in art.names():
        try:
            z: zarr.Array = art.zarr_array(name)
            shape, dtype, chunks = z.shape, z.dtype, z.chunks
        except ArtifactError as e:  # a damaged zarr.json (an edited dtype, say): say so, describe the rest
            print(f"  {name:<22} DAMAGED: {str(e).split(': ', 1)[-1]}; `sbrdf verify` reports it and "
                  f"`sbrdf verify --repair` has the next run recompute it")
            continue
        print(f"  {name:<22} {str(shape):<22} {str(dtype):<8} chunks {chunks}")
        want = declared.get(name)
        if want and (list(shape) != want.get("shape") or str(dtype) != want.get("dtype")):
            print(f"  {'':<22} DAMAGED: its node declared shape {tuple(want.get('shape') or ())} "
                  f"{want.get('dtype')}; `sbrdf verify --repair` has the next run recompute it")
    skip = {"provenance", "kind", "version", "token", "complete", "node", "layout", "file_digests"}
    for k, v in art.attrs.items():
        if k not in skip:
            print(f"  @{k}: {json.dumps(v)[:200]}")


def _same_place(a: str, b: str) -> bool:
    import os

    if "://" in a or "://" in b:
        return a.rstrip("/") == b.rstrip("/")
    return os.path.realpath(a) == os.path.realpath(b)


def _describe_other_zarr(url: str, why: str | None, artifacts) -> None:
    """A zarr store that is not an sbrdf artifact: say so, say what names it, list what it holds."""
    import zarr

    try:
        node = zarr.open(store=url, mode="r")
    except Exception as e:  # noqa: BLE001  (a damaged or foreign store: describe, never crash)
        print(f"{url}\n  not an sbrdf artifact, and not readable as zarr: {type(e).__name__}: {e}")
        return
    attrs = dict(node.attrs)
    kind = attrs.get("kind")
    what = f"a zarr {'group' if isinstance(node, zarr.Group) else 'array'}" + (f" of kind {kind!r}" if kind else "")
    print(f"{url}\n  not an sbrdf artifact: {what}, with no sbrdf provenance or token (not a node's output: "
          f"a plugin's side store, or written by hand)")
    names = [u for u, a in artifacts
             if any(isinstance(v, str) and _same_place(v, url)
                    for v in list(a.attrs.get("model_config", {}).values())
                    + list(a.provenance.get("parameters", {}).values()))]
    if names:
        print(f"  named by: {', '.join(names)} (their model reads it: keep it beside them)")
    if isinstance(node, zarr.Group):
        arrays = sorted(node.arrays(), key=lambda kv: kv[0])
        for name, z in arrays:
            print(f"  {name:<22} {str(z.shape):<22} {str(z.dtype):<8} chunks {z.chunks}")
    else:
        print(f"  {'(array)':<22} {str(node.shape):<22} {str(node.dtype):<8} chunks {node.chunks}")
    for k, v in attrs.items():
        if k != "kind":
            print(f"  @{k}: {json.dumps(v, default=str)[:200]}")


def fit_table(fits) -> str:
    """Seed 000 Table 3.4's fitting columns (time, average and maximum RMS) for ParamMaps artifacts, and the
    mean RMS at held-out samples (``held_out``: error where the fit was not trained).

    Time is the fitter's compute time summed over tiles (CPU seconds across
    workers), not the node's wall time.  The text columns widen to their
    longest cell up to a cap; a longer cell is cut with ``…`` so every row
    stays aligned under its header.
    """
    fmt = lambda x: f"{x:.4g}" if isinstance(x, (int, float)) else "-"  # noqa: E731
    cells = []
    for url, art in fits:
        summary = art.attrs.get("summary", {})
        model = art.attrs.get("model", "?") + describe_config(art.attrs.get("model_config", {}))
        u, v = art.attrs.get("texels", [0, 0])
        flagged = summary.get("texels_flagged_any", sum(summary.get("texels_flagged", {}).values()))
        cells.append(([url.rstrip("/").rsplit("/", 1)[-1], art.attrs.get("fitter") or "?", model],
                      [u * v, fmt(summary.get("fit_time_s")), fmt(summary.get("rms_mean")), fmt(summary.get("rms_max")),
                       fmt(summary.get("rms_holdout_mean")), flagged]))
    text_cols = [("artifact", 28, 40), ("fitter", 12, 20), ("model", 22, 48)]
    widths = [min(cap, max([least] + [len(row[0][k]) for row in cells])) for k, (_, least, cap) in enumerate(text_cols)]
    num_cols = [("texels", 9), ("fit_s", 9), ("avg_rms", 10), ("max_rms", 10), ("held_out", 10), ("flagged", 8)]

    def line(texts, numbers) -> str:
        left = " ".join(f"{_clip(t, w):<{w}}" for t, w in zip(texts, widths))
        return left + "".join(f" {n!s:>{w}}" for n, (_, w) in zip(numbers, num_cols))

    head = line([name for name, _, _ in text_cols], [name for name, _ in num_cols])
    return "\n".join([head, "-" * len(head)] + [line(texts, numbers) for texts, numbers in cells])


def _clip(text: str, width: int) -> str:
    """``text`` cut to ``width`` characters, its last one ``…`` where anything was cut."""
    return text if len(text) <= width else text[:width - 1] + "…"


def describe_config(cfg: dict) -> str:
    """A model's configuration (its declared parameters' values) as `` name=value`` pairs, scalars only:
    the table names no model's parameters, whatever model a fit used."""
    short = {k: v for k, v in cfg.items()
             if isinstance(v, (bool, int, float)) or (isinstance(v, str) and len(v) <= 16 and "/" not in v)}
    return "".join(f" {k}={json.dumps(v) if isinstance(v, bool) else v}" for k, v in short.items())


#: The name ``benchmarks/bench.py`` is loaded under (once per process).
BENCH_MODULE = "sbrdf_benchmarks_bench"


def bench_module():
    """``benchmarks/bench.py`` of the source checkout this package runs from: benchmark tooling is not part of
    the installed core, so ``sbrdf bench`` needs the checkout."""
    import importlib.util

    if BENCH_MODULE in sys.modules:
        return sys.modules[BENCH_MODULE]
    path = Path(__file__).resolve().parent.parent / "benchmarks" / "bench.py"
    if not path.is_file():
        raise SbrdfError(f"sbrdf bench needs the source checkout (benchmarks/ next to sbrdf_core/); {path} not found")
    spec = importlib.util.spec_from_file_location(BENCH_MODULE, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[BENCH_MODULE] = module  # before running it: its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def cmd_bench(args) -> int:
    return bench_module().main(args.stages, args.full, not args.no_images, args.log)


def _wait_options(p, help: str) -> None:
    p.add_argument("--wait", action="store_true", help=help)
    p.add_argument("--wait-timeout", type=float, default=None, metavar="SECONDS",
                   help="wait at most this long for the store (implies --wait)")


def _wait(args) -> bool | float:
    return args.wait_timeout if args.wait_timeout is not None else args.wait


#: Marks the handler :func:`configure_logging` installed, so a second call replaces it.
_HANDLER_TAG = "_sbrdf_cli"
#: The loggers of per-node summaries (``sbrdf.report.<node kind>``), which ``-q`` silences.
REPORT_LOGGER = "sbrdf.report"
#: Loggers whose level :func:`configure_logging` set, so a later call without ``-v``/``-q`` resets them.
_LEVELS_SET: set[str] = set()


def configure_logging(verbose: int, quiet: bool = False) -> None:
    """``-v`` INFO, ``-vv`` DEBUG for sbrdf's own loggers (core, library, installed plugins); others stay as they are.

    ``-q`` (``quiet``, without ``-v``) silences the per-node summaries of what the data lacked (the
    ``sbrdf.report`` loggers: pixels a capture made invalid); what they summarise stays in the artifacts'
    attributes, which ``sbrdf info`` shows.  Other warnings and errors still print.
    Without either nothing is configured: warnings reach stderr through Python's default handler, as before.
    """
    for name in _LEVELS_SET:  # an earlier main() in this process (tests, a notebook) set them: start afresh
        logging.getLogger(name).setLevel(logging.NOTSET)
    _LEVELS_SET.clear()
    if quiet and verbose <= 0:
        logging.getLogger(REPORT_LOGGER).setLevel(logging.ERROR)
        _LEVELS_SET.add(REPORT_LOGGER)
    if verbose <= 0:
        return
    from importlib.metadata import entry_points

    level = logging.INFO if verbose == 1 else logging.DEBUG
    names = {"sbrdf", "sbrdf_core", "sbrdf_lib"} | {ep.value.split(":")[0].split(".")[0]
                                                    for ep in entry_points(group="sbrdf")}
    for name in names:
        logging.getLogger(name).setLevel(level)
    _LEVELS_SET.update(names)
    root = logging.getLogger()
    for h in [h for h in root.handlers if getattr(h, _HANDLER_TAG, False)]:
        root.removeHandler(h)
    if not root.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        setattr(handler, _HANDLER_TAG, True)
        root.addHandler(handler)


def main(argv: list[str] | None = None) -> int:
    _registry_for.cache_clear()  # one registry per invocation, not per process (tests call main repeatedly)
    ap = argparse.ArgumentParser(prog="sbrdf", description="Measured surface appearance pipelines.")
    ap.add_argument("-p", dest="plugin", action="append", default=[], metavar="MODULE",
                    help="register a plugin module, or 'no:NAME' to disable an installed one")
    ap.add_argument("-v", "--verbose", action="count", default=0,
                    help="log what happens (node start and finish, cache reuse, prepare steps); -vv for debug detail")
    sub = ap.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="validate and execute a graph")
    p.add_argument("graph")
    p.add_argument("--scheduler", default="threads",
                   help="threads (default), sync, processes, or tcp://host:port of a dask.distributed scheduler")
    p.add_argument("--workers", type=int, default=None, help="threads/processes for local schedulers")
    p.add_argument("--store", default=None, help="override the graph's store (a path relative to the current directory)")
    p.add_argument("--only", nargs="+", help="run only these nodes (and what they need)")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress bars and no per-node summaries of what the data lacked (they stay in the "
                   "artifacts: sbrdf info); other warnings still print")
    p.add_argument("--var", action="append", default=[], metavar="NAME=VALUE",
                   help="give a value to one of the graph's ${variables} (repeatable)")
    p.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                   help="override a value: node.params.key=VALUE (node.key for a parameter), node.plugin=..., "
                   "store=...; VALUE is YAML (3, [1, 2], {a: 1}, text) (repeatable)")
    p.add_argument("--batch", default=None, metavar="CSV_OR_DIR",
                   help="run once per scan: a CSV (header: variable names, optional store column) or a folder of "
                   "capture folders (variables scan and path); one store per scan under the graph's store")
    p.add_argument("--concurrent", type=int, default=1, metavar="N",
                   help="with --batch: scans run at once, on a local scheduler or one cluster (default 1; bars "
                   "only when 1)")
    _wait_options(p, "if another run holds the store, wait for it instead of refusing")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("verify", help="read every chunk of a store's artifacts; report damage (exit 1) "
                       "and what a re-run recomputes")
    p.add_argument("store")
    p.add_argument("--repair", action="store_true",
                   help="drop the done markers of damaged chunks (remove broken artifacts) so the next run recomputes them")
    _wait_options(p, "wait for a run holding the store instead of refusing")
    p.set_defaults(func=cmd_verify)

    p = sub.add_parser("validate", help="check a graph without running anything")
    p.add_argument("graph")
    p.add_argument("--store", default=None)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("plugins", help="list node kinds and installed plugins with their parameters")
    p.add_argument("--category", default=None)
    p.set_defaults(func=cmd_plugins)

    p = sub.add_parser("info", help="describe an artifact or every artifact in a store")
    p.add_argument("store")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("bench", help="run the benchmarks (quick sizes) and regenerate docs/accuracy-vs-time.md; "
                       "says what it will cost before it starts")
    p.add_argument("stages", nargs="*", help="stages to run (default all, as benchmarks/stages.toml lists them)")
    sizes = p.add_mutually_exclusive_group()
    sizes.add_argument("--quick", dest="full", action="store_false",
                       help="quick sizes (the default; a few minutes on 2 idle cores)")
    sizes.add_argument("--full", dest="full", action="store_true",
                       help="full sizes (about an hour on 2 cores) instead of quick ones")
    p.set_defaults(full=False)
    p.add_argument("--no-images", action="store_true",
                   help="leave docs/img untouched: no docs renders, and the scripts run without --docs (their sections "
                   "and charts stay as they are; only the summary is rewritten)")
    p.add_argument("--log", default=None, help="the scripts' output (default runs/bench.log)")
    p.set_defaults(func=cmd_bench)

    _plugin_commands(sub, argv)
    args = ap.parse_args(argv)
    configure_logging(args.verbose, getattr(args, "quiet", False))
    tune_process(args)
    try:
        return args.func(args)
    except SbrdfError as e:
        full = _no_space(e, args)
        print(f"sbrdf: error: {e}" + (f" ({full})" if full else ""), file=sys.stderr)
        _traceback_if_verbose(args)
        return 2
    except KeyboardInterrupt:
        if args.command == "bench":
            print("sbrdf: bench interrupted; the summary was not rewritten (the scripts' output is in the log)",
                  file=sys.stderr)
        else:
            print("sbrdf: interrupted; re-run to resume from the chunks already written", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001  (no input gets a traceback: one line, the traceback with -v)
        print(f"sbrdf: error: {_one_line(e, args)}", file=sys.stderr)
        if not _traceback_if_verbose(args):
            print("sbrdf: (an unexpected error: run with -v for the traceback)", file=sys.stderr)
        return 1


def _no_space(error: BaseException, args=None) -> str | None:
    """"out of disk space on PATH" where ``error`` or an exception it was raised from is ENOSPC (or EDQUOT)."""
    import errno

    seen: set[int] = set()
    e: BaseException | None = error
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
            what = "out of disk space" if e.errno == errno.ENOSPC else "over the disk quota"
            where = e.filename or _store_of(args)
            return f"{what} on {where}" if where else what
        e = e.__cause__ or e.__context__
    return None


def _store_of(args) -> str | None:
    """The store a command writes (``--store``, a command's STORE, or the graph's ``store:``), if it can be told."""
    store = getattr(args, "store", None)
    if store:
        return str(store)
    graph = getattr(args, "graph", None)
    if graph:
        try:
            from .graph import graph_store

            return graph_store(graph)
        except Exception:  # noqa: BLE001  (only a better message was at stake)
            return None
    return None


def _one_line(error: BaseException, args=None) -> str:
    """An unexpected exception as one line: disk full said plainly, else its type and first line."""
    full = _no_space(error, args)
    if full:
        return full
    if isinstance(error, MemoryError):
        return "out of memory (MemoryError); a smaller graph, fewer workers, or limits: {max_memory} may help"
    text = str(error).strip().splitlines()
    first = text[0] if text else ""
    if len(first) > 500:
        first = first[:500] + "..."
    return f"{type(error).__name__}: {first}" if first else type(error).__name__


def _traceback_if_verbose(args) -> bool:
    """Print the current exception's traceback when ``-v`` was given; whether it was."""
    if getattr(args, "verbose", 0) <= 0:
        return False
    import traceback

    traceback.print_exc(file=sys.stderr)
    return True


def _plugin_commands(sub, argv: list[str] | None) -> None:
    """Subcommands plugins contribute (``sbrdf_commands``): declared from the registry the ``-p`` options select."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("-p", dest="plugin", action="append", default=[])
    known, _ = pre.parse_known_args(argv)
    try:
        reg = _registry(known)
    except SbrdfError as e:  # a broken plugin set: the core commands still work and report it
        logger.warning("plugin commands unavailable: %s", e)
        return
    for name in reg.names("command"):
        if name in sub.choices:
            logger.warning("plugin command %r ignored: sbrdf already has a command of that name", name)
            continue
        spec = reg.get("command", name)
        p = sub.add_parser(name, help=spec.summary)
        reg.load(spec).add_arguments(p)
        p.set_defaults(func=lambda args, _name=name, _reg=reg: _run_command(_reg, _name, args))


def _run_command(reg, name: str, args) -> int:
    """A plugin subcommand, bound to the invocation's registry so it sees the same plugin set."""
    from .contracts import Command, optional

    command: Command = reg.create("command", name, {})
    bind = optional(command, "bind", "command")
    if bind is not None:
        bind(reg)
    return command.run(args)


if __name__ == "__main__":
    sys.exit(main())
