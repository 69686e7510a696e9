"""``sbrdf bench``: run the benchmark scripts and regenerate ``docs/accuracy-vs-time.md``.

Tooling of the source checkout, not of the installed package: the ``sbrdf bench``
command loads this file from ``benchmarks/`` beside ``sbrdf_core/``
(:func:`sbrdf_core.cli.bench_module`) and says so when there is none.

The stages and the docs' illustrating renders are declared in
``benchmarks/stages.toml`` (so the core names no benchmark, graph or plugin).
Each script in ``benchmarks/`` owns one section of the report (``--docs``
rewrites it: a table and a plot stating machine, sizes and date) and prints
its figures as its last line.  This runs them one after another, at quick
sizes unless ``--full``, re-renders the documentation's images with the
project's own renderers, and writes a summary section with every last line.

Before it starts it says what it will cost: the stages, and an estimate per
stage from the wall times the last summary recorded (or from built-in quick
figures), scaled by this machine's load; then one line per stage as it starts
and as it ends, with the time spent and the time likely left.

``--no-images`` leaves ``docs/img/`` untouched: the documentation's renders
are not re-made, and the scripts run *without* ``--docs``, because ``--docs``
rewrites a stage's section together with its chart (a table with new figures
beside an old chart would disagree).  Their figures still go into the summary,
which says that the sections below it were not rewritten.  Should a script
write into ``docs/img/`` all the same, the files it changed are put back and
the run says so.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import date
from pathlib import Path

from sbrdf_core.errors import SbrdfError

#: The declaration of the stages and docs images, under the checkout's ``benchmarks/``.
STAGES_FILE = "stages.toml"


@dataclass(frozen=True)
class Stage:
    """One benchmark script: what it is called, what it measures, its quick-size wall time on 2 idle cores."""

    name: str
    script: str
    what: str
    quick_s: float = 60.0


@dataclass(frozen=True)
class Plan:
    """What ``benchmarks/stages.toml`` declares: the stages in report order, and the graphs whose renders
    illustrate the docs as ``(graph, node, image under docs/img/)``."""

    stages: dict[str, Stage]
    images: tuple[tuple[str, str, str], ...] = ()
    images_quick_s: float = 20.0


def load_plan(root: Path) -> Plan:
    """Read ``benchmarks/stages.toml`` of the checkout at ``root``."""
    import tomllib

    path = root / "benchmarks" / STAGES_FILE
    try:
        data = tomllib.loads(path.read_text())
        stages = {d["name"]: Stage(d["name"], d["script"], d.get("what", ""), float(d.get("quick_s", 60)))
                  for d in data.get("stage", [])}
        images = tuple((d["graph"], d["node"], d["image"]) for d in data.get("image", []))
    except (OSError, tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as e:
        raise SbrdfError(f"{path}: cannot read the benchmark stages: {type(e).__name__}: {e}") from e
    return Plan(stages, images, float(data.get("images_quick_s", 20)))


def repo_root() -> Path:
    root = Path(__file__).resolve().parent.parent
    if not (root / "benchmarks").is_dir():
        raise SbrdfError(f"sbrdf bench needs the source checkout (benchmarks/ next to sbrdf_core/); not found under {root}")
    return root


def run_stage(root: Path, stage: Stage, full: bool, log, docs: bool = True, status=None) -> tuple[str, float, int]:
    """Run one script; returns its last line, wall seconds and exit code (output goes to ``log``).

    ``docs=False`` runs it without ``--docs`` (nothing under docs/ is written);
    ``status(elapsed_s, line)`` is called with each line it prints.
    """
    script = root / "benchmarks" / stage.script
    if not script.exists():
        return f"{stage.name}: (no script {script.name})", 0.0, 127
    cmd = [sys.executable, str(script)] + (["--docs"] if docs else []) + ([] if full else ["--quick"])
    log.write(f"$ {' '.join(cmd)}\n")
    log.flush()
    t0 = time.perf_counter()
    last = ""
    with subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          bufsize=1, env={**os.environ, "PYTHONUNBUFFERED": "1"}) as proc:
        for line in proc.stdout or ():
            log.write(line)
            if line.strip():
                last = line.rstrip("\n")
                if status:
                    status(time.perf_counter() - t0, last)
        rc = proc.wait()
    log.write("\n")
    log.flush()
    return last, time.perf_counter() - t0, rc


def render_images(root: Path, store: Path, log, images: tuple[tuple[str, str, str], ...]) -> float:
    """Run the illustrating graphs into ``store`` and copy their PNGs into docs/img."""
    import shutil

    from sbrdf_core.graph import load_graph
    from sbrdf_core.registry import default_registry
    from sbrdf_core.runner import Runner

    t0 = time.perf_counter()
    reg = default_registry()
    for graph in dict.fromkeys(g for g, _, _ in images):
        g = load_graph(str(root / "graphs" / graph), reg, store=str(store / graph.removesuffix(".yaml")))
        Runner(reg, progress=False).run(g)
    for graph, node, image in images:
        shutil.copyfile(store / graph.removesuffix(".yaml") / node / "image.png", root / "docs" / "img" / image)
        log.write(f"docs/img/{image} <- {graph} node {node}\n")
    return time.perf_counter() - t0


def summary_section(results: list[tuple[str, str, float, int]], full: bool, machine: str, docs: bool = True,
                    stages: dict[str, Stage] | None = None) -> str:
    rows = ["| stage | what | wall s | figures (the script's last line) |", "|---|---|---:|---|"]
    for name, line, wall, rc in results:
        what = stages[name].what if stages and name in stages else "documentation images"
        status = "" if rc == 0 else f" **(exit {rc})**"
        rows.append(f"| {name} | {what} | {wall:.0f} | `{line}`{status} |")
    total = sum(r[2] for r in results)
    return "\n".join([
        "<!-- summary:begin (generated by sbrdf bench; do not edit by hand) -->",
        "## Summary",
        "",
        f"`sbrdf bench{' --full' if full else ''}{'' if docs else ' --no-images'}` on {machine}, "
        f"{date.today().isoformat()}: {'full' if full else 'quick'} sizes, {total / 60:.1f} minutes in all. "
        + ("Each stage's section below states its sizes; quick sizes are for checking the trade-offs, not for quoting."
           if docs else "With `--no-images` the stages' sections below (tables and charts) were not rewritten: "
           "they may be older than these figures."),
        "",
        *rows,
        "<!-- summary:end -->",
        "",
    ])


def recorded_walls(report: Path) -> tuple[dict[str, float], str]:
    """Wall seconds per stage from the report's summary table, and the line saying where they were taken."""
    text = report.read_text() if report.exists() else ""
    if "<!-- summary:begin" not in text:
        return {}, ""
    section = text.split("<!-- summary:begin", 1)[1].split("<!-- summary:end -->", 1)[0]
    walls = {m.group(1): float(m.group(2)) for m in re.finditer(r"^\| (\w+) \| [^|]* \| ([0-9.]+) \|", section, re.M)}
    m = re.search(r"^`sbrdf bench([^`]*)` on (.*?): (quick|full) sizes", section, re.M)
    return walls, (f"{m.group(3)}|{m.group(2)}" if m else "")


def estimate(names: list[str], images: bool, full: bool, report: Path, plan: Plan) -> tuple[dict[str, float], str]:
    """Seconds per stage (``images`` included when it runs) and a sentence saying where the figures come from."""
    quick = {**{n: st.quick_s for n, st in plan.stages.items()}, "images": plan.images_quick_s}
    walls, where = recorded_walls(report)
    sizes, _, machine_date = where.partition("|")
    wanted = names + (["images"] if images else [])
    if sizes == ("full" if full else "quick") and walls:
        est = {n: walls.get(n, quick.get(n, 60) * (1 if not full else 20)) for n in wanted}
        missing = [n for n in wanted if n not in walls]
        src = f"the last recorded run, on {machine_date}"
        if missing:
            src += f"; {', '.join(missing)} not recorded there, guessed"
    elif not full:
        est = {n: quick.get(n, 60) for n in wanted}
        src = "quick sizes on 2 idle cores"
    else:
        est = {n: (quick[n] if n == "images" else 60 * 60 / len(plan.stages)) for n in wanted}
        src = "full sizes: about an hour on 2 idle cores in all, no per-stage record"
    return est, src


def load_factor() -> tuple[float, str]:
    """How much longer than on idle cores, judging by the 1-minute load average (others' work shares the cores)."""
    try:
        load = os.getloadavg()[0]
    except OSError:
        return 1.0, ""
    cores = os.cpu_count() or 1
    factor = max(1.0, (load + 1) / cores)
    return factor, f"1-minute load average {load:.1f} on {cores} cores"


def _minutes(s: float) -> str:
    return f"{s:.0f} s" if s < 90 else f"{s / 60:.1f} min"


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()} if folder.is_dir() else {}


def _restore(folder: Path, before: dict[str, bytes]) -> list[str]:
    """Put ``folder``'s files back as ``before`` had them; returns the names that had changed."""
    changed = []
    if folder.is_dir():
        for p in folder.iterdir():
            if p.is_file() and p.name not in before:
                p.unlink()
                changed.append(p.name)
    for name, data in before.items():
        p = folder / name
        if not p.is_file() or p.read_bytes() != data:
            p.write_bytes(data)
            changed.append(name)
    return sorted(changed)


def _report_module(root: Path):
    """benchmarks/report.py of ``root`` (loaded by path: a ``report`` module imported elsewhere must not stand in)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("sbrdf_bench_report", root / "benchmarks" / "report.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(stages: list[str] | None, full: bool, images: bool, log_path: str | None) -> int:
    root = repo_root()
    report_mod = _report_module(root)
    report = root / "docs" / "accuracy-vs-time.md"
    plan = load_plan(root)

    names = stages or list(plan.stages)
    unknown = [n for n in names if n not in plan.stages]
    if unknown:
        raise SbrdfError(f"unknown bench stage(s) {unknown}; choose from {list(plan.stages)}")
    log_file = Path(log_path) if log_path else root / "runs" / "bench.log"
    log_file.parent.mkdir(parents=True, exist_ok=True)

    est, src = estimate(names, images, full, report, plan)
    factor, load = load_factor()
    total = sum(est.values())
    print(f"sbrdf bench: {len(names)} stage{'s' if len(names) != 1 else ''} at {'full' if full else 'quick'} sizes"
          f"{', then the docs images' if images else ' (--no-images: docs/img and the stage sections stay as they are)'}: "
          + ", ".join(f"{n} ~{_minutes(est[n])}" for n in est), flush=True)
    print(f"    estimate: about {_minutes(total)} (from {src})"
          + (f"; with the {load}, nearer {_minutes(total * factor)}" if factor > 1.05 else "")
          + f". Output: {log_file}", flush=True)

    tty = sys.stdout.isatty()

    def status(elapsed: float, line: str) -> None:
        if tty:
            width = shutil.get_terminal_size((100, 20)).columns
            sys.stdout.write(("\r    " + f"{elapsed:.0f} s  {line}")[: width - 1].ljust(width - 1))
            sys.stdout.flush()

    img_dir = root / "docs" / "img"
    results = []
    t_start = time.perf_counter()
    with log_file.open("w") as log:
        for i, name in enumerate(names, 1):
            left = sum(est[n] for n in names[i - 1:]) + est.get("images", 0)
            print(f"[{i}/{len(names)}] {name}: {plan.stages[name].what} (~{_minutes(est[name] * factor)}; "
                  f"{_minutes(time.perf_counter() - t_start)} so far, ~{_minutes(left * factor)} to go) ...", flush=True)
            before = None if images else _snapshot(img_dir)
            line, wall, rc = run_stage(root, plan.stages[name], full, log, docs=images, status=status)
            if tty:
                sys.stdout.write("\r")
            print(f"    {'done' if rc == 0 else f'FAILED (exit {rc}; see {log_file})'} in {_minutes(wall)}: {line}", flush=True)
            if before is not None:
                touched = _restore(img_dir, before)
                if touched:
                    print(f"    {name} wrote docs/img/{{{', '.join(touched)}}} although run without --docs: put back",
                          flush=True)
            results.append((name, line, wall, rc))
        if images:
            import tempfile

            print(f"images: rendering the docs' pictures (~{_minutes(est['images'] * factor)}) ...", flush=True)
            with tempfile.TemporaryDirectory() as tmp:
                wall = render_images(root, Path(tmp), log, plan.images)
            print(f"    done in {_minutes(wall)}", flush=True)
            results.append(("images", "docs/img/" + ", ".join(i for _, _, i in plan.images), wall, 0))
    summary = summary_section(results, full, report_mod.machine(), docs=images, stages=plan.stages)
    report_mod.replace_section("summary", summary, report)
    print(f"report: {report} (log: {log_file}); {_minutes(time.perf_counter() - t_start)} in all")
    return 0 if all(r[3] == 0 for r in results) else 1
