"""Hostile and unlucky inputs, each through the real ``sbrdf`` command: what comes out.

Imported by ``benchmarks/integrity.py`` (which prints the combined last line);
runnable alone.  Every case runs ``sbrdf`` in a subprocess (a hang is a
timeout, not a stuck benchmark) against a store in a temporary folder, with a
*sentinel* folder beside it: files with content that nothing may write, rename
or delete.  Each case ends in one verdict, the worst that happened:

* ``outside``: the sentinel (or another store) changed;
* ``hang``: a command ran past its timeout;
* ``traceback``: a command printed a Python traceback;
* ``stuck``: a store that a re-run should resume failed the re-run;
* ``silent``: bad input accepted (exit 0 where an error was due), damage
  ``sbrdf verify`` did not report, or a cached result that differs from a
  fresh run's;
* ``clear``: a clear error (or, for a store to resume, a re-run that worked).

Cases a machine cannot set up (a read-only store when running as root, where
permissions do not bind) are skipped and not counted.  Last line:
``hostile: tried=N clear=C silent=S outside=O stuck=K tracebacks=T hangs=H``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from collections import Counter
from pathlib import Path

SBRDF = [str(Path(sys.executable).parent / "sbrdf")]
VERDICTS = ("clear", "silent", "outside", "stuck", "traceback", "hang")
WORST = ("outside", "hang", "traceback", "stuck", "silent", "clear")

PIPELINE = """\
name: hostile
store: {store}
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [16, 16], poses: 12, model: lambert, noise: 0.01, seed: 1}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}, params: {{tile: 8}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lambert}}}}
"""

SEPARABLE = """\
name: hostile-separable
store: {store}
nodes:
  material:
    kind: SampleModel
    params: {{model: ward, params: {{rho_d: 0.3, rho_s: 0.2, alpha: 0.2}}, texels: [1, 1], size_mm: [0.001, 0.001],
             poses: 400, directions: random}}
  nd:
    kind: Fit
    plugin: nd
    in: {{samples: material}}
    params: {{factors: '{factors}', size: 8}}
"""

SAMPLE = """\
name: hostile-sample
store: {store}
nodes:
  material:
    kind: SampleModel
    params: {{model: ward, params: {params}, texels: [2, 2], poses: 16}}
"""

SCENE = """\
name: hostile-scene
store: {store}
nodes:
  capture: {{kind: Capture, plugin: synthetic, params: {{texels: [8, 8], poses: 8, model: lambert, seed: 1}}}}
  register: {{kind: Register, plugin: texel-aligned, in: {{capture: capture}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}}}
  fit: {{kind: Fit, plugin: lm, in: {{samples: reflectance}}, params: {{model: lambert}}}}
  quantize: {{kind: Quantize, plugin: linear, in: {{params: fit}}, params: {{dtype: uint8}}}}
  scene: {{kind: Render, plugin: cpu, in: {{material: quantize}}, params: {{scene: '{scene}'}}}}
"""

CAMERA = {"width": 96, "height": 72, "focal_px": 160.0, "texels": [8, 8], "intensity": 1.5e5,
          "effects": ["falloff"], "carrier_supersample": 1, "seed": 3}

FOLDER = """\
name: hostile-folder
store: {store}
nodes:
  capture: {{kind: Capture, plugin: {plugin}, params: {params}}}
"""


def tree_digest(path: Path) -> str:
    """Names, link targets and contents of everything under ``path`` (links not followed)."""
    h = hashlib.sha256()
    if not os.path.lexists(path):
        return "missing"
    for p in sorted([path, *path.rglob("*")]) if path.is_dir() and not path.is_symlink() else [path]:
        h.update(str(p.relative_to(path.parent)).encode())
        if p.is_symlink():
            h.update(b"->" + os.readlink(p).encode())
        elif p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


class Case:
    """One case's commands and what it found; ``verdict`` is the worst of them."""

    def __init__(self, root: Path, name: str):
        self.root, self.name = root, name
        self.found: set[str] = set()  # what went wrong: names from WORST
        self.watched: list[tuple[Path, str]] = []
        self.log: list[str] = []

    def sentinel(self) -> Path:
        s = self.root / "sentinel"
        (s / "sub").mkdir(parents=True, exist_ok=True)
        (s / "keep.txt").write_text("the user's file\n")
        (s / "sub" / "data.bin").write_bytes(bytes(range(256)) * 4)
        self.watch(s)
        return s

    def watch(self, path: Path) -> None:
        self.watched.append((path, tree_digest(path)))

    def sbrdf(self, *args, timeout: float = 120, ok: bool | None = None) -> subprocess.CompletedProcess:
        """Run ``sbrdf ARGS``.  ``ok=True``: exit 0 is due (else *stuck*); ``ok=False``: an error is due (else *silent*)."""
        env = {**os.environ, "PYTHONWARNINGS": "ignore"}
        t0 = time.perf_counter()
        try:
            r = subprocess.run(SBRDF + [str(a) for a in args], capture_output=True, text=True, timeout=timeout, env=env,
                               cwd=self.root, start_new_session=True)
        except subprocess.TimeoutExpired as e:
            self.found.add("hang")
            self.log.append(f"{' '.join(map(str, args))}: no answer in {timeout:.0f} s")
            if e.cmd:
                subprocess.run(["pkill", "-KILL", "-f", str(self.root)], check=False)
            return subprocess.CompletedProcess(args, -9, "", "")
        out = r.stdout + r.stderr
        if "Traceback (most recent call last)" in out:
            self.found.add("traceback")
        if ok is True and r.returncode != 0:
            self.found.add("stuck")
        if ok is False and r.returncode == 0:
            self.found.add("silent")
        last = [line for line in out.strip().splitlines() if line.strip()][-1:] or [""]
        self.log.append(f"{' '.join(map(str, args))[:60]}: rc {r.returncode} in {time.perf_counter() - t0:.1f} s: "
                        f"{last[0][:150]}")
        return r

    def silent(self, why: str) -> None:
        self.found.add("silent")
        self.log.append(why)

    def verdict(self) -> str:
        for path, digest in self.watched:
            if tree_digest(path) != digest:
                self.found.add("outside")
                self.log.append(f"{path} changed")
        return next((v for v in WORST if v in self.found), "clear")


# -- stores to damage ----------------------------------------------------------------------------


def finished(root: Path, base: Path, name: str) -> tuple[Path, Path]:
    """A copy of the finished pipeline store and its graph."""
    store = root / name
    shutil.copytree(base / "store", store, symlinks=True)
    graph = root / f"{name}.yaml"
    graph.write_text(PIPELINE.format(store=store))
    return store, graph


def set_attrs(group: Path, **attrs) -> None:
    meta = json.loads((group / "zarr.json").read_text())
    meta.setdefault("attributes", {}).update(attrs)
    (group / "zarr.json").write_text(json.dumps(meta))


def chunk_files(array: Path) -> list[Path]:
    return sorted(p for p in (array / "c").rglob("*") if p.is_file())


def same_arrays(a: Path, b: Path, node: str, arrays: tuple[str, ...]) -> bool:
    import numpy as np
    import zarr

    try:
        return all(np.array_equal(zarr.open_array(str(a / node / n), mode="r")[...],
                                  zarr.open_array(str(b / node / n), mode="r")[...], equal_nan=True) for n in arrays)
    except Exception:
        return False


# -- the cases -----------------------------------------------------------------------------------


def factors_outside_dir(c: Case, base: Path) -> None:
    s = c.sentinel()
    g = c.root / "g.yaml"
    g.write_text(SEPARABLE.format(store=c.root / "store", factors=s))
    c.sbrdf("validate", g, ok=False)
    c.sbrdf("run", g, ok=False)


def factors_outside_file(c: Case, base: Path) -> None:
    s = c.sentinel()
    g = c.root / "g.yaml"
    g.write_text(SEPARABLE.format(store=c.root / "store", factors=s / "keep.txt"))
    c.sbrdf("validate", g, ok=False)
    c.sbrdf("run", g, ok=False)


def factors_store_root(c: Case, base: Path) -> None:
    store, _ = finished(c.root, base, "store")
    c.watch(store / "fit")
    g = c.root / "g.yaml"
    g.write_text(SEPARABLE.format(store=store, factors=store))
    c.sbrdf("validate", g, ok=False)
    c.sbrdf("run", g, ok=False)


def factors_other_artifact(c: Case, base: Path) -> None:
    store, _ = finished(c.root, base, "store")
    c.watch(store / "fit")
    g = c.root / "g.yaml"
    g.write_text(SEPARABLE.format(store=store, factors=store / "fit"))
    c.sbrdf("validate", g, ok=False)
    c.sbrdf("run", g, ok=False)


def link_in_artifact(c: Case, base: Path) -> None:
    """A chunk directory of fit/rms replaced by a link to a copy of it outside the store."""
    store, graph = finished(c.root, base, "store")
    s = c.root / "sentinel"
    shutil.copytree(store / "fit" / "rms" / "c", s)
    shutil.rmtree(store / "fit" / "rms" / "c")
    os.symlink(s, store / "fit" / "rms" / "c")
    c.watch(s)
    c.sbrdf("verify", store, ok=False)
    c.sbrdf("verify", "--repair", store)
    c.sbrdf("run", graph, ok=True)


def virtual_folder_into_user_dir(c: Case, base: Path) -> None:
    s = c.sentinel()
    params = {"path": str(s), "camera": {"device": "virtual-camera", "params": CAMERA}, "poses": 2,
              "exposures": [1.0], "durable": False}
    g = c.root / "g.yaml"
    g.write_text(FOLDER.format(store=c.root / "store", plugin="virtual-folder", params=json.dumps(params)))
    c.sbrdf("run", g, ok=False)


def killed_inside_array_creation(c: Case, base: Path) -> None:
    """What a kill between the artifact marker and an array's zarr.json leaves: a partial artifact without it."""
    store, graph = finished(c.root, base, "store")
    set_attrs(store / "fit", complete=False)
    shutil.rmtree(store / "fit" / "rms")
    shutil.rmtree(store / "fit" / "_done" / "rms", ignore_errors=True)
    c.sbrdf("run", graph, ok=True)
    c.sbrdf("verify", store, ok=True)
    if not same_arrays(store, base / "store", "fit", ("rms",)):
        c.silent("resumed fit/rms differs from the uninterrupted run's")


def killed_before_marker_arrays(c: Case, base: Path) -> None:
    store, graph = finished(c.root, base, "store")
    set_attrs(store / "reflectance", complete=False)
    shutil.rmtree(store / "reflectance" / "_done")
    c.sbrdf("run", graph, ok=True)
    c.sbrdf("verify", store, ok=True)


def damage_behind_incomplete(c: Case, base: Path) -> None:
    store, graph = finished(c.root, base, "store")
    set_attrs(store / "fit", complete=False)
    f = chunk_files(store / "fit" / "rms")[0]
    b = bytearray(f.read_bytes())
    b[len(b) // 2] ^= 0x04
    f.write_bytes(bytes(b))
    c.sbrdf("verify", store, ok=False)
    c.sbrdf("verify", "--repair", store)
    c.sbrdf("run", graph, ok=True)
    if not same_arrays(store, base / "store", "fit", ("rms",)):
        c.silent("fit/rms after the re-run differs from the undamaged store's")


def chunk_file_is_a_directory(c: Case, base: Path) -> None:
    store, graph = finished(c.root, base, "store")
    f = chunk_files(store / "fit" / "rms")[0]
    f.unlink()
    f.mkdir()
    c.sbrdf("verify", store, ok=False)
    c.sbrdf("verify", "--repair", store)
    c.sbrdf("run", graph, ok=True)


def artifact_linked_to_other_store(c: Case, base: Path) -> None:
    store, graph = finished(c.root, base, "store")
    other, _ = finished(c.root, base, "other")
    set_attrs(other / "fit", complete=False)  # so that a run following the link would write there
    shutil.rmtree(store / "fit")
    os.symlink(other / "fit", store / "fit")
    c.watch(other)
    c.sbrdf("verify", store, ok=False)
    c.sbrdf("run", graph)


def artifact_is_a_file(c: Case, base: Path) -> None:
    store, graph = finished(c.root, base, "store")
    shutil.rmtree(store / "fit")
    (store / "fit").write_text("not an artifact")
    c.sbrdf("verify", store, ok=False)
    c.sbrdf("run", graph)


def metadata_is_a_fifo(c: Case, base: Path) -> None:
    store, graph = finished(c.root, base, "store")
    meta = store / "fit" / "rms" / "zarr.json"
    meta.unlink()
    os.mkfifo(meta)
    c.sbrdf("verify", store, timeout=60, ok=False)
    c.sbrdf("run", graph, timeout=120)


def lock_is_a_link(c: Case, base: Path) -> None:
    store, graph = finished(c.root, base, "store")
    s = c.sentinel()
    lock = store / ".sbrdf.lock"
    if os.path.lexists(lock):
        os.remove(lock)
    os.symlink(s / "keep.txt", lock)
    c.sbrdf("verify", store)
    c.sbrdf("run", graph)


def info_edited_dtype(c: Case, base: Path) -> None:
    store, _ = finished(c.root, base, "store")
    meta = store / "fit" / "rms" / "zarr.json"
    m = json.loads(meta.read_text())
    m["data_type"] = "complex128"
    meta.write_text(json.dumps(m))
    c.sbrdf("info", store)


def read_only_store(c: Case, base: Path) -> str | None:
    """An intact store verified where nothing can be written (as root, through a read-only bind mount)."""
    store, _ = finished(c.root, base, "store")
    target, mounted = store, None
    if os.geteuid() == 0:  # root writes through chmod
        target = mounted = c.root / "ro"
        mounted.mkdir()
        if subprocess.run(["mount", "--bind", "-o", "ro", str(store), str(mounted)], capture_output=True).returncode:
            return "running as root, and no read-only bind mount may be made here"
        subprocess.run(["mount", "-o", "remount,bind,ro", str(mounted)], capture_output=True)
    else:
        for p in [store, *store.rglob("*")]:
            os.chmod(p, 0o555 if p.is_dir() else 0o444)
    try:
        if os.access(target, os.W_OK):
            return "the store stays writable here"
        c.watch(store)
        c.sbrdf("verify", target, ok=True)  # an intact store verifies read-only
        c.sbrdf("verify", "--repair", target, ok=False)
    finally:
        if mounted:
            subprocess.run(["umount", str(mounted)], check=True)
        else:
            for p in [store, *store.rglob("*")]:
                os.chmod(p, 0o755 if p.is_dir() else 0o644)
    return None


def sample_params(params: str):
    def case(c: Case, base: Path) -> None:
        g = c.root / "g.yaml"
        g.write_text(SAMPLE.format(store=c.root / "store", params=params))
        c.sbrdf("validate", g, ok=False)
    return case


def huge_integer(c: Case, base: Path) -> None:
    g = c.root / "g.yaml"
    g.write_text(SAMPLE.format(store=c.root / "store", params="{rho_d: 0.3}").replace("poses: 16", "poses: " + "9" * 5000))
    c.sbrdf("validate", g, ok=False)


def integer_too_large_for_float(c: Case, base: Path) -> None:
    g = c.root / "g.yaml"
    g.write_text(PIPELINE.format(store=c.root / "store").replace("noise: 0.01", "noise: 1" + "0" * 400))
    c.sbrdf("validate", g, ok=False)


def http_store(c: Case, base: Path) -> None:
    g = c.root / "g.yaml"
    g.write_text(PIPELINE.format(store="http://127.0.0.1:1/x"))
    if c.sbrdf("validate", g).returncode == 0:
        c.sbrdf("run", g, ok=False)


def scene_special(path: str, validate_only: bool = False):
    def case(c: Case, base: Path) -> None:
        g = c.root / "g.yaml"
        g.write_text(SCENE.format(store=c.root / "store", scene=path))
        c.sbrdf("validate", g, timeout=60, ok=False)
        if not validate_only:
            c.sbrdf("run", g, timeout=60, ok=False)
    return case


def validate_special(path: str):
    def case(c: Case, base: Path) -> None:
        c.sbrdf("validate", path, timeout=60, ok=False)
    return case


def capture_folder(c: Case, base: Path) -> Path:
    """A small capture folder written by the virtual camera (once, then copied)."""
    cached = base / "folder"
    if not cached.exists():
        params = {"path": str(cached), "camera": {"device": "virtual-camera", "params": CAMERA}, "poses": 3,
                  "exposures": [1.0], "durable": False}
        g = base / "make-folder.yaml"
        g.write_text(FOLDER.format(store=base / "folder-store", plugin="virtual-folder", params=json.dumps(params)))
        subprocess.run(SBRDF + ["run", str(g)], check=True, capture_output=True)
    folder = c.root / "scan"
    shutil.copytree(cached, folder)
    return folder


def folder_graph(c: Case, folder: Path, store: Path) -> Path:
    g = c.root / f"{store.name}.yaml"
    g.write_text(FOLDER.format(store=store, plugin="folder", params=json.dumps({"path": str(folder)})))
    return g


def image_in_subfolder_replaced(c: Case, base: Path) -> None:
    folder = capture_folder(c, base)
    manifest = json.loads((folder / "capture.json").read_text())
    (folder / "images" / "sub").mkdir()
    for pose in manifest["poses"]:
        for e in pose["exposures"]:
            name = Path(e["file"]).name
            (folder / "images" / name).rename(folder / "images" / "sub" / name)
            e["file"] = f"images/sub/{name}"
    (folder / "capture.json").write_text(json.dumps(manifest))
    c.sbrdf("run", folder_graph(c, folder, c.root / "store"), ok=True)
    first = folder / manifest["poses"][0]["exposures"][0]["file"]
    other = folder / manifest["poses"][1]["exposures"][0]["file"]
    shutil.copyfile(other, first)
    c.sbrdf("run", folder_graph(c, folder, c.root / "store"), ok=True)
    c.sbrdf("run", folder_graph(c, folder, c.root / "fresh"), ok=True)
    if not same_arrays(c.root / "store", c.root / "fresh", "capture", ("images",)):
        c.silent("the changed image was not noticed: the cached capture differs from a fresh run's")


def png_bomb(c: Case, base: Path) -> None:
    """An 8-bit grey PNG of 30000 x 30000 pixels (900 MB decoded) in about 1 MB, in place of a pose's image."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from tests.acquisition.test_capture_hostile import png_bomb as write_bomb

    folder = capture_folder(c, base)
    manifest = json.loads((folder / "capture.json").read_text())
    write_bomb(folder / manifest["poses"][1]["exposures"][0]["file"], 30000)
    # Refusing it takes a header read; decoding it, then the other poses, is what a hang looks like.
    c.sbrdf("run", folder_graph(c, folder, c.root / "store"), timeout=30, ok=False)


#: (name, function, in the --quick set)
CASES = [
    ("nd factors: a directory outside the store", factors_outside_dir, True),
    ("nd factors: a file outside the store", factors_outside_file, False),
    ("nd factors: the store root", factors_store_root, True),
    ("nd factors: another node's artifact", factors_other_artifact, False),
    ("a chunk directory linked out of the store", link_in_artifact, True),
    ("virtual-folder into a folder of the user's", virtual_folder_into_user_dir, True),
    ("killed inside array creation (array missing)", killed_inside_array_creation, True),
    ("killed inside array creation (markers missing)", killed_before_marker_arrays, False),
    ("damage behind complete: false", damage_behind_incomplete, True),
    ("a chunk file replaced by a directory", chunk_file_is_a_directory, False),
    ("an artifact linked to another store", artifact_linked_to_other_store, True),
    ("an artifact path that is a plain file", artifact_is_a_file, False),
    ("an array's zarr.json replaced by a FIFO", metadata_is_a_fifo, False),
    (".sbrdf.lock a link out of the store", lock_is_a_link, True),
    ("sbrdf info, array dtype edited", info_edited_dtype, False),
    ("sbrdf verify on a read-only store", read_only_store, False),
    ("SampleModel params: unknown name", sample_params("{rho_d: 0.3, bogus: 1}"), True),
    ("SampleModel params: rho_d 1e300", sample_params("{rho_d: 1.0e+300}"), True),
    ("SampleModel params: a string", sample_params("{rho_d: abc}"), False),
    ("SampleModel params: a date", sample_params("{rho_d: 2024-01-01}"), False),
    ("an integer of 5000 digits", huge_integer, True),
    ("an integer too large for a float", integer_too_large_for_float, False),
    ("store: http://127.0.0.1:1/x", http_store, True),
    ("scene: /dev/zero", scene_special("/dev/zero"), False),
    ("scene: /dev/urandom", scene_special("/dev/urandom"), False),
    ("sbrdf validate /dev/zero", validate_special("/dev/zero"), True),
    ("sbrdf validate /dev/urandom", validate_special("/dev/urandom"), False),
    ("capture image in a subfolder replaced", image_in_subfolder_replaced, False),
    ("a decompression-bomb PNG in a capture folder", png_bomb, False),
]


def run(quick: bool = False, keep: str | None = None, out=print) -> Counter:
    """Run the cases; returns counts of ``tried`` and of each verdict."""
    base = Path(keep or tempfile.mkdtemp(prefix="sbrdf-hostile-"))
    base.mkdir(parents=True, exist_ok=True)
    counts: Counter = Counter()
    try:
        graph = base / "pipeline.yaml"
        graph.write_text(PIPELINE.format(store=base / "store"))
        subprocess.run(SBRDF + ["run", str(graph)], check=True, capture_output=True)
        out(f"{'case':<50} verdict")
        for i, (name, fn, in_quick) in enumerate(CASES):
            if quick and not in_quick:
                continue
            root = base / f"case{i:02d}"
            root.mkdir()
            case = Case(root, name)
            skipped = fn(case, base)
            if skipped:
                out(f"{name:<50} skipped: {skipped}")
                continue
            v = case.verdict()
            counts["tried"] += 1
            counts[v] += 1
            out(f"{name:<50} {v}")
            if v != "clear":
                for line in case.log:
                    out(f"    {line.replace(str(root), '<case>')}")
            if not keep:
                shutil.rmtree(root, ignore_errors=True)
    finally:
        if not keep:
            shutil.rmtree(base, ignore_errors=True)
    return counts


def summary(counts: Counter) -> str:
    return " ".join(f"{k}={counts[k]}" for k in ("tried", "clear", "silent", "outside", "stuck")) + \
        f" tracebacks={counts['traceback']} hangs={counts['hang']}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the cases marked quick only")
    ap.add_argument("--keep", default=None, help="keep the stores under this folder")
    args = ap.parse_args(argv)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    counts = run(args.quick, args.keep)
    print(textwrap.dedent("""
        verdict: the worst that happened in the case (outside > hang > traceback > stuck > silent > clear)."""))
    print(f"hostile: {summary(counts)}")
    return 0 if counts["clear"] == counts["tried"] else 1


if __name__ == "__main__":
    sys.exit(main())
