"""Digest every artifact the shipped graphs make, to prove a refactor changed no result.

    python scripts/artifact_digests.py record before.json      # on the old code
    python scripts/artifact_digests.py record after.json       # on the new code
    python scripts/artifact_digests.py compare before.json after.json

``record`` runs each graph of ``graphs/`` (threads scheduler, one worker, so
reductions happen in one order) into a fresh store under a temporary
directory and hashes, per artifact, every array's decoded values (dtype,
shape, bytes), its attributes without the provenance that names a time, a
host or a path, and the decoded pixels of its side files (PNG, EXR).  Arrays
that hold measured durations (``*time_s``) are skipped: they are the one
thing a run may not repeat.  ``compare`` lists every difference and exits 1
if there is one.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: Provenance entries that change from run to run without the result changing.
VOLATILE = {"created", "host", "user", "python", "url", "file", "sha256", "token", "sbrdf_version", "version",
            "entry_point", "distribution", "elapsed_s", "duration_s", "started", "finished", "path"}


def _volatile(key: str) -> bool:
    """Durations and their containers: the one thing identical runs do not repeat."""
    return key in VOLATILE or key.endswith(("_s", "_ms")) or key.startswith("gpu_ms") or key in (
        "seconds", "run", "timings")


def _clean(value):
    """Attributes without durations, and absolute paths (where the store or checkout lies) reduced to a marker."""
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in sorted(value.items()) if not _volatile(k)}
    if isinstance(value, list):
        return [_clean(v) for v in value]
    if isinstance(value, str) and value.startswith("/"):
        return "<path>"
    return value


def _hash(*parts: bytes) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p)
    return h.hexdigest()[:20]


def _side_file(path: Path) -> str | None:
    if path.suffix == ".png":
        import matplotlib.image

        return _hash(np.ascontiguousarray(matplotlib.image.imread(path)).tobytes())
    if path.suffix == ".exr":
        import OpenEXR

        with OpenEXR.File(str(path)) as f:
            return _hash(*(np.ascontiguousarray(c.pixels).tobytes() for _, c in sorted(f.channels().items())))
    if path.suffix in (".json", ".txt", ".csv"):
        try:
            return _hash(json.dumps(_clean(json.loads(path.read_text())), sort_keys=True).encode())
        except ValueError:
            return _hash(path.read_bytes())
    return None


def digest_store(store: Path) -> dict[str, str]:
    import zarr

    out: dict[str, str] = {}
    for marker in sorted(store.rglob(".sbrdf-artifact")):
        art = marker.parent
        name = art.relative_to(store).as_posix()
        group = zarr.open_group(str(art), mode="r")
        # attributes are kept as text, so a difference can be read, not only detected
        out[f"{name}:attrs"] = json.dumps(_clean(dict(group.attrs)), sort_keys=True, default=str)
        for path, arr in sorted(_arrays(group), key=lambda kv: kv[0]):
            if path.split("/")[-1].endswith("time_s"):
                continue
            data = np.ascontiguousarray(arr[...])
            out[f"{name}/{path}"] = _hash(str(data.dtype).encode(), str(data.shape).encode(), data.tobytes(),
                                          json.dumps(_clean(dict(arr.attrs)), sort_keys=True, default=str).encode())
        for f in sorted(art.rglob("*")):
            if f.is_file() and "_done" not in f.parts and f.name not in ("zarr.json", ".sbrdf-artifact"):
                d = _side_file(f)
                if d is not None:
                    out[f"{name}:{f.relative_to(art).as_posix()}"] = d
    return out


def _arrays(group, prefix=""):
    import zarr

    for key, member in group.members():
        if key.startswith("_"):
            continue
        if isinstance(member, zarr.Array):
            yield prefix + key, member
        else:
            yield from _arrays(member, prefix + key + "/")


def record(out: Path, graphs: list[str]) -> None:
    result: dict[str, dict[str, str]] = {}
    with tempfile.TemporaryDirectory(prefix="sbrdf-digest-") as tmp:
        for graph in graphs:
            store = Path(tmp) / Path(graph).stem
            cmd = [sys.executable, "-c", "import sys; from sbrdf_core.cli import main; sys.exit(main())", "run", graph, "--store", str(store), "-q", "--workers", "1"]
            print("running", graph, flush=True)
            run = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env={**os.environ, "PYTHONHASHSEED": "0"})
            if run.returncode:
                result[graph] = {"error": run.stderr[-2000:]}
                print(run.stderr[-2000:], file=sys.stderr)
                continue
            result[graph] = digest_store(store)
            print(f"  {len(result[graph])} digests", flush=True)
    out.write_text(json.dumps(result, indent=1, sort_keys=True))


def compare(a: Path, b: Path) -> int:
    before, after = json.loads(a.read_text()), json.loads(b.read_text())
    diffs = 0
    for graph in sorted(set(before) | set(after)):
        x, y = before.get(graph, {}), after.get(graph, {})
        for d in (x, y):  # recorded by an older version of this script: clean again
            for key in [k for k in d if k.endswith(":attrs")]:
                d[key] = json.dumps(_clean(json.loads(d[key])), sort_keys=True)
        for key in sorted(set(x) | set(y)):
            if x.get(key) != y.get(key):
                diffs += 1
                a, b = str(x.get(key)), str(y.get(key))
                if len(a) > 60 or len(b) > 60:  # attributes: show where they part
                    i = next((i for i, (p, q) in enumerate(zip(a, b)) if p != q), min(len(a), len(b)))
                    a, b = a[max(0, i - 60):i + 60], b[max(0, i - 60):i + 60]
                print(f"{graph}  {key}: {a} -> {b}")
    total = sum(len(v) for v in after.values())
    print(f"artifact_digests: graphs={len(after)} digests={total} differences={diffs}")
    return 1 if diffs else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out", type=Path)
    r.add_argument("graphs", nargs="*", help="default: every graphs/*.yaml")
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    args = ap.parse_args(argv)
    if args.cmd == "record":
        record(args.out.resolve(), args.graphs or sorted(str(p.relative_to(ROOT)) for p in (ROOT / "graphs").glob("*.yaml")))
        return 0
    return compare(args.before, args.after)


if __name__ == "__main__":
    sys.exit(main())
