"""Damage a finished store in N ways; count what ``sbrdf verify`` and a re-run notice.

What it does
------------
1. Runs a small demo-like graph (synthetic capture -> texel-aligned register ->
   reflectance -> lm/lambert fit -> linear uint8 quantize -> preview render)
   into a temporary store: the *original*.
2. For each case, copies the original, damages the copy one way, then

   * ``sbrdf verify COPY`` (in process): *found by verify* when it exits 1 and
     names the damaged artifact;
   * a re-run of the same graph: *found by the run* when it reports the node
     damaged (a note, the node recomputed) or stops with an sbrdf error;
   * if damage is left (a full verify still finds it): ``sbrdf verify
     --repair`` and a second re-run;
   * *repaired* when a final verify finds nothing and every array equals the
     original's (wall-clock timing arrays excluded) and the side files exist.

   A case is *detected* when verify or the run noticed it, *silent* otherwise.
   A raw traceback (anything but an sbrdf error) is reported as ``CRASH`` and
   counted as a traceback.

3. Then the hostile and unlucky inputs of ``benchmarks/hostile.py``, each
   through the real ``sbrdf`` command in a subprocess with a sentinel folder
   beside the store (see there for the verdicts).

Sizes: full (no arguments) is texels [64, 64] x 24 poses and every case;
``--quick`` is texels [24, 20] x 12 poses, the first 8 damage cases and the
quick hostile cases (about a minute on 2 cores once the fitting kernels are
compiled).  The last line counts both parts: ``integrity: tried=N clear=C
silent=S outside=O stuck=K tracebacks=T hangs=H repaired=R`` (``repaired``:
damage cases whose store ends equal to the undamaged one).

How to run
----------
::

    .venv/bin/python benchmarks/integrity.py --quick
    .venv/bin/python benchmarks/integrity.py            # every case
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import os
import shutil
import sys
import tempfile
import textwrap
import traceback
from pathlib import Path

import numpy as np
import zarr

from sbrdf_core.artifacts import KINDS
from sbrdf_core.cli import main as sbrdf
from sbrdf_core.errors import SbrdfError
from sbrdf_core.graph import load_graph
from sbrdf_core.registry import Registry
from sbrdf_core.runner import Runner
from sbrdf_core.store import members

sys.path.insert(0, str(Path(__file__).resolve().parent))
import hostile  # noqa: E402

GRAPH = """\
name: integrity
store: {store}
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: {texels}, poses: {poses}, model: lambert, noise: 0.01, seed: 1}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}, params: {{tile: 8}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lambert}}}}
  quantize: {{kind: Quantize, plugin: linear, in: {{params: fit}}, params: {{dtype: uint8}}}}
  render: {{kind: Render, plugin: preview, in: {{material: quantize}}}}
"""


# -- the damage ---------------------------------------------------------------------------------


def chunks(store: Path, array: str) -> list[Path]:
    return sorted(p for p in (store / array / "c").rglob("*") if p.is_file())


def delete_chunk(array):
    return lambda s: chunks(s, array)[0].unlink()


def flip_bit(array):
    def damage(s):
        c = chunks(s, array)[0]
        b = bytearray(c.read_bytes())
        b[len(b) // 2] ^= 0x04
        c.write_bytes(bytes(b))
    return damage


def truncate(array, keep=None):
    def damage(s):
        c = chunks(s, array)[-1]
        b = c.read_bytes()
        c.write_bytes(b[: (len(b) * 2 // 3) if keep is None else keep])
    return damage


def random_bytes(array):
    def damage(s):
        c = chunks(s, array)[0]
        c.write_bytes(np.random.default_rng(7).bytes(c.stat().st_size))
    return damage


def swap_chunks(array):
    def damage(s):
        a, b = chunks(s, array)[:2]
        da, db = a.read_bytes(), b.read_bytes()
        a.write_bytes(db)
        b.write_bytes(da)
    return damage


def edit_meta(array, key, value):
    def damage(s):
        p = s / array / "zarr.json"
        meta = json.loads(p.read_text())
        meta[key] = value(meta[key]) if callable(value) else value
        p.write_text(json.dumps(meta))
    return damage


def delete(path):
    return lambda s: (shutil.rmtree if (s / path).is_dir() else os.remove)(s / path)


def truncate_file(path):
    return lambda s: (s / path).write_bytes((s / path).read_bytes()[:100])


def garbage(path):
    return lambda s: (s / path).write_bytes(b"\x00\xff not json" * 3)


def delete_marker(array):
    node, name = array.split("/", 1)
    return lambda s: sorted(p for p in (s / node / "_done" / name.replace("/", ".") / "c").rglob("*") if p.is_file())[0].unlink()


#: (case, node it damages, damage); the first 8 are the --quick set.
CASES = [
    ("deleted chunk (fit params/rho_d)", "fit", delete_chunk("fit/params/rho_d")),
    ("bit flip (reflectance f_r)", "reflectance", flip_bit("reflectance/f_r")),
    ("truncated chunk (quantize textures)", "quantize", None),  # filled in below: its texture array's name
    ("random bytes (fit rms)", "fit", random_bytes("fit/rms")),
    ("edited shape (fit params/rho_d zarr.json)", "fit", edit_meta("fit/params/rho_d", "shape", lambda sh: [2 * sh[0], *sh[1:]])),
    ("edited dtype (quantize error zarr.json)", "quantize", edit_meta("quantize/error", "data_type", "float64")),
    ("deleted side file (render/image.png)", "render", delete("render/image.png")),
    ("deleted done marker (capture images)", "capture", delete_marker("capture/images")),
    ("deleted chunk (reflectance f_r)", "reflectance", delete_chunk("reflectance/f_r")),
    ("bit flip in a shard (register radiance)", "register", flip_bit("register/radiance")),
    ("bit flip (capture images)", "capture", flip_bit("capture/images")),
    ("chunk emptied to 0 bytes (fit samples)", "fit", truncate("fit/samples", keep=0)),
    ("random bytes (register valid)", "register", random_bytes("register/valid")),
    ("two chunks swapped (fit rms)", "fit", swap_chunks("fit/rms")),
    ("deleted array zarr.json (register valid)", "register", delete("register/valid/zarr.json")),
    ("deleted group zarr.json (quantize)", "quantize", delete("quantize/zarr.json")),
    ("garbage group zarr.json (fit)", "fit", garbage("fit/zarr.json")),
    ("edited chunk grid (reflectance valid zarr.json)", "reflectance",
     edit_meta("reflectance/valid", "chunk_grid", lambda g: {**g, "configuration": {"chunk_shape": [4, 4, 12]}})),
    ("all chunks of an array deleted (reflectance valid)", "reflectance", delete("reflectance/valid/c")),
    ("truncated side file (render/image.exr)", "render", truncate_file("render/image.exr")),
    ("deleted marker array (fit rms)", "fit", delete("fit/_done/rms")),
    ("deleted marker file and group zarr.json (render)", "render",
     lambda s: (delete("render/.sbrdf-artifact")(s), delete("render/zarr.json")(s))),
]


# -- running ------------------------------------------------------------------------------------


TIMINGS = {a.name for kind in KINDS.values() for a in kind.arrays if a.timing}


def read_store(store: Path) -> dict[str, np.ndarray]:
    out = {}
    for node in sorted(p for p in store.iterdir() if (p / "zarr.json").exists()):
        for name, m in members(zarr.open_group(str(node), mode="r")):
            if isinstance(m, zarr.Array) and not name.startswith("_done") and name not in TIMINGS:
                out[f"{node.name}/{name}"] = np.asarray(m[...])
    return out


def same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        x.dtype == b[k].dtype and x.shape == b[k].shape and np.array_equal(x, b[k], equal_nan=x.dtype.kind == "f")
        for k, x in a.items())


def verify(store: Path, *extra: str) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        rc = sbrdf(["verify", *extra, str(store)])
    return rc, out.getvalue()


def rerun(graph: Path, registry: Registry, node: str) -> tuple[str, bool]:
    """(what the run said about the damaged node, whether it noticed)."""
    try:
        rep = Runner(registry).run(load_graph(graph, registry))
    except SbrdfError as e:
        return f"error: {str(e).splitlines()[0].replace(str(graph.parent), '')[:90]}", True
    except Exception as e:  # a raw traceback: the failure this benchmark exists to rule out
        return f"CRASH {type(e).__name__}: {e} {traceback.format_exc(limit=-1)}", False
    r = rep[node]
    return r.status + (" (damage noted)" if r.notes else ""), bool(r.notes) or r.status != "cached"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller store, first 8 damage cases, quick hostile cases")
    ap.add_argument("--keep", default=None, help="keep the stores under this folder")
    args = ap.parse_args(argv)
    texels, poses = ([24, 20], 12) if args.quick else ([64, 64], 24)
    cases = CASES[:8] if args.quick else CASES
    registry = Registry()
    logging.getLogger("sbrdf_core.runner").setLevel(logging.ERROR)  # the run's damage notes are in its report
    root = Path(args.keep or tempfile.mkdtemp(prefix="sbrdf-integrity-"))
    root.mkdir(parents=True, exist_ok=True)
    try:
        (root / "original.yaml").write_text(GRAPH.format(store=root / "original", texels=texels, poses=poses))
        Runner(registry).run(load_graph(root / "original.yaml", registry))
        original = read_store(root / "original")
        texture = next(p.name for p in (root / "original" / "quantize" / "textures").iterdir() if p.is_dir())
        detected = silent = crashes = repaired = 0
        print(f"store: texels {texels} x {poses} poses; {len(cases)} cases\n")
        print(f"{'case':<56} {'verify':<9} {'re-run':<44} {'repaired'}")
        for i, (case, node, damage) in enumerate(cases):
            if damage is None:
                damage = truncate(f"quantize/textures/{texture}")
            store = root / f"case{i:02d}"
            shutil.copytree(root / "original", store)
            graph = root / f"case{i:02d}.yaml"
            graph.write_text(GRAPH.format(store=store, texels=texels, poses=poses))
            damage(store)
            rc, out = verify(store)
            by_verify = rc == 1 and f"{store}/{node}  " in out and "DAMAGED" in out
            said, by_run = rerun(graph, registry, node)
            if verify(store)[0] != 0:  # left for verify --repair (damage no cached-artifact check can see)
                verify(store, "--repair")
                said2, _ = rerun(graph, registry, node)
                said += f"; after --repair: {said2}"
            rc_final, _ = verify(store)
            ok = rc_final == 0 and same(read_store(store), original) and (store / "render" / "image.png").exists()
            noticed = by_verify or by_run
            detected += noticed
            crashed = "CRASH" in said
            silent += not noticed and not crashed
            crashes += crashed
            repaired += ok
            print(f"{case:<56} {'found' if by_verify else 'MISSED':<9} {said[:44]:<44} {'yes' if ok else 'NO'}")
            if "CRASH" in said or not ok:
                print(f"    {said}")
            if not args.keep:
                shutil.rmtree(store)
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    print(textwrap.dedent("""
        verify: `sbrdf verify` (reads every chunk); re-run: what the same graph's next run did to the damaged node
        (cached, resumed = only the damaged chunks rewritten, computed = whole artifact); repaired: final verify clean
        and every array equal to the undamaged store's."""))
    print(f"\ndamage: cases={len(cases)} detected={detected} silent={silent} crashes={crashes} repaired={repaired}\n")
    counts = hostile.run(args.quick, f"{args.keep}/hostile" if args.keep else None)
    print(f"\nhostile: {hostile.summary(counts)}")
    counts["tried"] += len(cases)
    counts["clear"] += len(cases) - silent - crashes
    counts["silent"] += silent
    counts["traceback"] += crashes
    print(f"integrity: {hostile.summary(counts)} repaired={repaired}")
    return 0 if counts["clear"] == counts["tried"] else 1


if __name__ == "__main__":
    sys.exit(main())
