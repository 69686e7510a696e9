"""sbrdf-capture/1 folders: writer/reader round trip, validation errors, crash-safe resume."""

from __future__ import annotations

import copy
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sbrdf_capture.photograph import capture_to_folder, orbit_poses
from sbrdf_lib.capture_folder import (
    JOURNAL,
    MANIFEST,
    CaptureFolderError,
    CaptureFolderWriter,
    load_manifest,
    read_journal,
    validate_folder,
)

SMALL = {"width": 96, "height": 72, "focal_px": 130.0, "texels": [16, 16]}


def make_camera(registry, **params):
    cam = registry.create("device", "virtual-camera", {**SMALL, **params})
    cam.bind(registry)
    return cam


@pytest.fixture(scope="module")
def folder(tmp_path_factory, registry):
    """A small complete 8-bit capture with 2-exposure brackets."""
    path = tmp_path_factory.mktemp("cf") / "scan"
    cam = make_camera(registry, effects=["response", "falloff"])
    light, R, t = orbit_poses(4)
    capture_to_folder(cam, path, light, R, t, [[0.5, 2.0]] * 4, durable=False)
    return path


def test_round_trip(folder, registry):
    m = validate_folder(folder)
    assert m.complete and [p.id for p in m.poses] == [0, 1, 2, 3]
    assert not (folder / JOURNAL).exists()
    assert all(len(p.exposures) == 2 and (folder / p.exposures[0].file).is_file() for p in m.poses)
    data = json.loads((folder / MANIFEST).read_text())
    assert data["format"] == "sbrdf-capture/1" and data["simulation"]["effects"] == ["falloff", "response"]
    light, R, t = orbit_poses(4)
    np.testing.assert_allclose([p.R for p in m.poses], R)
    np.testing.assert_allclose([p.light_pos_mm for p in m.poses], light)
    src = registry.create("capture", "folder", {"path": str(folder)})
    d = src.describe()
    assert (d.n_poses, d.height, d.width) == (4, 72, 96) and d.camera["model"] == "pinhole"
    assert d.sample["fiducials"]["dictionary"] == "DICT_4X4_50" and len(d.sample["fiducials"]["markers"]) == 12
    image, valid = src.read_pose(1)
    assert image.shape == (72, 96, 3) and image.dtype == np.float32 and valid.shape == (72, 96) and valid.any()


def test_writer_refuses_a_finished_capture_and_a_different_header(folder, registry, tmp_path):
    cam = make_camera(registry, effects=["response", "falloff"])
    with pytest.raises(CaptureFolderError, match="already holds a complete capture"):
        CaptureFolderWriter(folder, cam.sample_info(), cam.camera_info(), cam.light_info())
    w = CaptureFolderWriter(tmp_path / "x", cam.sample_info(), cam.camera_info(), cam.light_info())
    w.write_pose(0, [0, 0, 100], np.eye(3), [0, 0, 300], [(np.zeros((72, 96, 3), np.uint8), 0.1)])
    other = make_camera(registry, effects=["response", "falloff"], focal_px=131.0)
    with pytest.raises(CaptureFolderError, match="different sample/camera/light header"):
        CaptureFolderWriter(tmp_path / "x", other.sample_info(), other.camera_info(), other.light_info())
    with pytest.raises(CaptureFolderError, match=r"image shape \(10, 10, 3\)"):
        w.write_pose(1, [0, 0, 100], np.eye(3), [0, 0, 300], [(np.zeros((10, 10, 3), np.uint8), 0.1)])
    with pytest.raises(CaptureFolderError, match="exposure time must be positive"):
        w.write_pose(1, [0, 0, 100], np.eye(3), [0, 0, 300], [(np.zeros((72, 96, 3), np.uint8), -0.1)])
    assert w.done_ids == {0}  # nothing recorded for the rejected poses
    assert not (tmp_path / "x" / "images" / "p00001_e0.png").exists()


def _mutate(folder: Path, tmp: Path, edit) -> Path:
    dst = tmp / "bad"
    shutil.copytree(folder, dst)
    data = json.loads((dst / MANIFEST).read_text())
    edit(data, dst)
    (dst / MANIFEST).write_text(json.dumps(data))
    return dst


def _set(path, value):
    def edit(data, _):
        node = data
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value
    return edit


def _remove_image(data, dst):
    os.remove(dst / data["poses"][2]["exposures"][1]["file"])


def _corrupt_image(data, dst):
    (dst / data["poses"][1]["exposures"][0]["file"]).write_bytes(b"not a png at all, certainly not one")


def _resize_image(data, dst):
    import cv2

    cv2.imwrite(str(dst / data["poses"][3]["exposures"][0]["file"]), np.zeros((10, 12, 3), np.uint8))


def _escape(data, dst):
    shutil.copy(dst / data["poses"][0]["exposures"][0]["file"], dst.parent / "outside.png")
    data["poses"][0]["exposures"][0]["file"] = "images/../../outside.png"


def _symlink_escape(data, dst):
    shutil.copy(dst / data["poses"][0]["exposures"][0]["file"], dst.parent / "outside2.png")
    os.symlink(dst.parent / "outside2.png", dst / "images" / "link.png")
    data["poses"][0]["exposures"][0]["file"] = "images/link.png"


def _manifest_symlink_out(data, dst):
    """capture.json is a link to a file outside the folder (_mutate then writes the manifest through it)."""
    outside = dst.parent / "elsewhere.json"
    outside.write_text("{}")
    os.remove(dst / MANIFEST)
    os.symlink(outside, dst / MANIFEST)


BAD = {
    "manifest_symlink": (_manifest_symlink_out, r"capture.json: the manifest capture.json is a link to '.*elsewhere.json' "
                                                r"and resolves to .*, outside the capture folder"),
    "light_at_origin": (_set(["poses", 1, "light_pos_mm"], [0, 0, 0]),
                        r"capture.json: poses\[1\] \(id 1\)\.light_pos_mm: the light is at the origin"),
    "light_below_sample": (_set(["poses", 2, "light_pos_mm"], [100.0, 50.0, -20.0]),
                           r"capture.json: poses\[2\] \(id 2\)\.light_pos_mm: z = -20 mm: the light is at or below the "
                           r"sample plane"),
    "light_in_sample_plane": (_set(["poses", 3, "light_pos_mm"], [300.0, 0.0, 0.0]),
                              r"poses\[3\] \(id 3\)\.light_pos_mm: z = 0 mm: the light is at or below"),
    "format": (_set(["format"], "sbrdf-capture/2"), r"capture.json: format: is 'sbrdf-capture/2'"),
    "dictionary": (_set(["sample", "fiducials", "dictionary"], "DICT_9X9_7"), r"sample.fiducials.dictionary: unknown fiducial dictionary 'DICT_9X9_7'.*DICT_4X4_50"),
    "rotation": (_set(["poses", 2, "camera", "R"], [[1, 0, 0], [0, 1, 0.1], [0, 0, 1]]), r"poses\[2\] \(id 2\)\.camera\.R: not orthonormal"),
    "reflection": (_set(["poses", 1, "camera", "R"], [[1, 0, 0], [0, 1, 0], [0, 0, -1]]), r"poses\[1\] \(id 1\)\.camera\.R: is a reflection"),
    "negative_time": (_set(["poses", 3, "exposures", 1, "time_s"], -0.5), r"poses\[3\] \(id 3\)\.exposures\[1\]\.time_s: exposure time must be positive"),
    "absolute_path": (_set(["poses", 0, "exposures", 0, "file"], "/etc/passwd.png"), r"poses\[0\] \(id 0\)\.exposures\[0\]\.file: '/etc/passwd.png' leads outside"),
    "dotdot": (_escape, r"leads outside the capture folder"),
    "symlink": (_symlink_escape, r"resolves to .*outside the capture folder"),
    "missing_image": (_remove_image, r"poses\[2\] \(id 2\)\.exposures\[1\]\.file: image 'images/p00002_e1.png' is missing"),
    "unreadable_image": (_corrupt_image, r"p00001_e0.png: unreadable image \(poses\[1\] \(id 1\)\.exposures\[0\]\.file\)"),
    "size_mismatch": (_resize_image, r"p00003_e0.png: image is 12x10 but camera.width x camera.height is 96x72"),
    "duplicate_id": (_set(["poses", 1, "id"], 0), r"poses\[1\]\.id: pose id 0 appears twice"),
    "bad_K": (_set(["camera", "K"], [[100, 0, 50], [0, 100, 40]]), r"camera.K: expected a 3x3 matrix"),
    "response_table": (_set(["camera", "response"], {"type": "table", "values": [0, 1, 2]}), r"camera.response.values: expected 256 or 65536"),
    "incomplete": (_set(["complete"], False), r"complete: false - the capture was interrupted"),
    "no_poses": (_set(["poses"], []), r"poses: the capture has no poses"),
    "light": (_set(["light", "intensity"], -1), r"light.intensity: must be positive"),
    "wrong_extension": (_set(["poses", 0, "exposures", 0, "file"], "images/p0.jpg"), r"unsupported image type"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_validation_errors_name_file_pose_and_field(case, folder, tmp_path, registry):
    edit, pattern = BAD[case]
    bad = _mutate(folder, tmp_path, edit)
    with pytest.raises(CaptureFolderError, match=pattern):
        validate_folder(bad)
    # Through a one-node graph: the same error, and no artifact left behind.
    from sbrdf_core.runner import run_graph

    graph = tmp_path / "g.yaml"
    graph.write_text(f"name: bad\nstore: {tmp_path / 'store'}\nnodes:\n"
                     f"  capture: {{kind: Capture, plugin: folder, params: {{path: {bad}}}}}\n")
    with pytest.raises(CaptureFolderError, match=pattern):
        run_graph(str(graph))
    assert not (tmp_path / "store" / "capture" / "zarr.json").exists()


def test_not_json_and_missing_manifest(tmp_path):
    (tmp_path / "a").mkdir()
    with pytest.raises(CaptureFolderError, match=r"capture.json: missing"):
        load_manifest(tmp_path / "a")
    (tmp_path / "a" / MANIFEST).write_text("{oops")
    with pytest.raises(CaptureFolderError, match=r"capture.json: not valid JSON \(line 1"):
        load_manifest(tmp_path / "a")


def test_fingerprint_changes_with_files(folder, registry, tmp_path):
    copy_ = tmp_path / "copy"
    shutil.copytree(folder, copy_)
    src = registry.create("capture", "folder", {"path": str(copy_)})
    before = src.fingerprint()
    assert before == registry.create("capture", "folder", {"path": str(copy_)}).fingerprint()
    img = copy_ / "images" / "p00000_e0.png"
    img.write_bytes(img.read_bytes() + b"\0")
    assert src.fingerprint() != before


KILLER = textwrap.dedent("""\
    import os, signal, sys
    import numpy as np
    from sbrdf_core.registry import Registry
    import sbrdf_lib.capture_folder as cf
    from sbrdf_capture.photograph import capture_to_folder, orbit_poses

    kill_at = int(sys.argv[2])
    real = cf._write_atomic
    calls = [0]
    def write(path, data, durable):
        if path.suffix != ".json" and not path.name.endswith(".journal"):
            calls[0] += 1
            if calls[0] == kill_at:  # mid-pose: exposure 0 of this pose is on disk, exposure 1 is not
                os.kill(os.getpid(), signal.SIGKILL)
        real(path, data, durable)
    cf._write_atomic = write
    reg = Registry()
    cam = reg.create("device", "virtual-camera", {PARAMS})
    cam.bind(reg)
    light, R, t = orbit_poses(6)
    capture_to_folder(cam, sys.argv[1], light, R, t, [[0.5, 2.0]] * 6)
""")


def test_killed_capture_resumes_to_identical_files(tmp_path, registry):
    params = {**SMALL, "effects": ["response", "noise", "motor_error", "falloff"], "bit_depth": 16}
    script = tmp_path / "killer.py"
    script.write_text(KILLER.replace("{PARAMS}", repr(params)))
    killed = tmp_path / "killed"
    proc = subprocess.run([sys.executable, str(script), str(killed), "8"], capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    # Killed while writing pose 3 (its 8th image): poses 0-2 recorded, the folder does not look complete.
    assert [p.id for p in read_journal(killed)] == [0, 1, 2]
    assert (killed / "images" / "p00003_e0.png").exists() and not (killed / "images" / "p00003_e1.png").exists()
    with pytest.raises(CaptureFolderError, match="complete: false"):
        validate_folder(killed)
    assert [p.id for p in validate_folder(killed, allow_incomplete=True).poses] == [0, 1, 2]

    # Resume in a fresh process-state camera, and capture the same thing uninterrupted.
    light, R, t = orbit_poses(6)
    for target in (killed, tmp_path / "whole"):
        cam = make_camera(registry, **{k: v for k, v in params.items() if k not in SMALL})
        capture_to_folder(cam, target, light, R, t, [[0.5, 2.0]] * 6)
    files = sorted(p.relative_to(killed) for p in killed.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "whole") for p in (tmp_path / "whole").rglob("*") if p.is_file())
    assert len([f for f in files if f.suffix == ".png"]) == 12
    for f in files:
        assert (killed / f).read_bytes() == (tmp_path / "whole" / f).read_bytes(), f"{f} differs after resume"


def test_torn_journal_line_is_dropped(folder, tmp_path, registry):
    cam = make_camera(registry, effects=[])
    light, R, t = orbit_poses(3)
    assert capture_to_folder(cam, tmp_path / "s", light, R, t, 1.0, stop_after=2) is None
    with open(tmp_path / "s" / JOURNAL, "ab") as f:
        f.write(b'{"id": 2, "light_pos')  # a writer killed mid-line
    assert [p.id for p in read_journal(tmp_path / "s")] == [0, 1]
    m = capture_to_folder(cam, tmp_path / "s", light, R, t, 1.0)
    assert [p.id for p in m.poses] == [0, 1, 2] and m.complete
    assert m.poses[0].exposures[0].file.endswith(".exr")


def test_manifest_json_round_trip_is_stable(folder):
    from sbrdf_lib.capture_folder import parse_manifest

    m = load_manifest(folder)
    again = parse_manifest(copy.deepcopy(m.to_json()))
    assert again.to_json() == m.to_json()


# -- issue 21: the manifest is inside the folder; physically impossible input is refused or counted ------------------


def test_a_manifest_linked_inside_the_folder_is_fine_and_a_journal_linked_out_is_refused(folder, registry, tmp_path):
    inside = tmp_path / "inside"
    shutil.copytree(folder, inside)
    (inside / "versions").mkdir()
    os.replace(inside / MANIFEST, inside / "versions" / "v1.json")
    os.symlink(Path("versions") / "v1.json", inside / MANIFEST)
    assert [p.id for p in validate_folder(inside).poses] == [0, 1, 2, 3]

    # A writer resuming a folder whose journal links elsewhere would append to that file: refused, nothing written.
    cam = make_camera(registry, effects=["response", "falloff"])
    w = CaptureFolderWriter(tmp_path / "scan", cam.sample_info(), cam.camera_info(), cam.light_info())
    w.write_pose(0, [0, 0, 100], np.eye(3), [0, 0, 300], [(np.zeros((72, 96, 3), np.uint8), 0.1)])
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    os.remove(tmp_path / "scan" / JOURNAL)
    os.symlink(victim, tmp_path / "scan" / JOURNAL)
    with pytest.raises(CaptureFolderError, match=r"capture.journal: the journal capture.journal is a link to .*outside"):
        CaptureFolderWriter(tmp_path / "scan", cam.sample_info(), cam.camera_info(), cam.light_info())
    with pytest.raises(CaptureFolderError, match="outside the capture folder"):
        read_journal(tmp_path / "scan")
    assert victim.read_text() == "precious\n"


@pytest.mark.parametrize("light,says", [([0, 0, 0], "the light is at the origin"), ([10, 20, -1], "z = -1 mm: the light is at or below")])
def test_the_writer_refuses_a_light_at_the_origin_or_below_before_writing(registry, tmp_path, light, says):
    cam = make_camera(registry, effects=["response", "falloff"])
    w = CaptureFolderWriter(tmp_path / "scan", cam.sample_info(), cam.camera_info(), cam.light_info())
    with pytest.raises(CaptureFolderError, match=rf"new pose 7 \(id 7\)\.light_pos_mm: {says}"):
        w.write_pose(7, light, np.eye(3), [0, 0, 300], [(np.zeros((72, 96, 3), np.uint8), 0.1)])
    assert w.done_ids == set() and not list((tmp_path / "scan" / "images").iterdir())


def _float_folder(path: Path, images: list[np.ndarray], white_level=None) -> Path:
    """A linear (EXR) capture folder with the given radiance images, one exposure of 1 s each."""
    H, W, _ = images[0].shape
    camera = {"width": W, "height": H, "K": [[20.0, 0, W / 2], [0, 20.0, H / 2], [0, 0, 1]], "dist": [0, 0, 0, 0, 0],
              "response": "linear"}
    if white_level is not None:
        camera["white_level"] = white_level
    w = CaptureFolderWriter(path, {"size_mm": [100, 100], "fiducials": None}, camera,
                            {"type": "point", "intensity": 1.0}, durable=False)
    for i, img in enumerate(images):
        w.write_pose(i, [100.0 * i, 0, 600], np.eye(3), [0, 0, 500], [(img.astype(np.float32), 1.0)])
    w.finish()
    return path


@pytest.mark.parametrize("white_level", [None, 1.0], ids=["no-white-level", "white-level"])
def test_negative_radiance_beyond_the_noise_tolerance_is_invalid_and_counted(registry, tmp_path, caplog, white_level):
    rng = np.random.default_rng(3)
    img = (0.5 + 0.4 * rng.random((12, 16, 3))).astype(np.float32)
    img[0, :4] = -1e-3               # noise around zero (0.1 % of full scale): not counted, kept as measured
    img[5, 3:8, 1] = -0.2            # 5 pixels clearly negative in one channel: impossible, invalid
    img[9, 9] = [-0.5, -0.4, -0.3]   # and one more
    folder = _float_folder(tmp_path / "scan", [img, np.full((12, 16, 3), 0.3, np.float32)], white_level=white_level)
    src = registry.create("capture", "folder", {"path": str(folder)})
    src.describe()
    with caplog.at_level("DEBUG", logger="sbrdf.capture.folder"):
        radiance, valid = src.read_pose(0)
    assert not valid[5, 3:8].any() and not valid[9, 9]
    assert np.allclose(radiance[0, :4], -1e-3)  # noise: unclamped
    if white_level is None:  # valid too (with a white level they are under-exposed, hence invalid anyway)
        assert valid[0, :4].all() and int((~valid).sum()) == 6
    else:
        assert int((~valid).sum()) == 10
    assert src.negative_pixels == {0: 6}
    assert "6 of 192 pixels have negative radiance" in caplog.text and "p00000_e0.exr" in caplog.text
    assert all(r.levelname == "DEBUG" for r in caplog.records)  # per pose: debug only, the node warns once
    _, valid1 = src.read_pose(1)
    assert valid1.all() and src.negative_pixels == {0: 6}
    line, attrs = src.read_report()
    assert "1 of 2 poses have pixels with negative radiance" in line and "poses[0] (id 0): 6 pixels" in line
    assert attrs == {"negative_radiance_pixels": {"0": 6}}

    # Through the Capture node: the stored validity mask says so.
    from sbrdf_core.runner import run_graph

    graph = tmp_path / "g.yaml"
    graph.write_text(f"name: neg\nstore: {tmp_path / 'store'}\nnodes:\n"
                     f"  capture: {{kind: Capture, plugin: folder, params: {{path: {folder}}}}}\n")
    run_graph(str(graph))
    import zarr

    valid_array = zarr.open_group(str(tmp_path / "store" / "capture"), mode="r")["valid"]
    assert isinstance(valid_array, zarr.Array)  # the Capture node stores its mask as an array, not a group
    stored = np.asarray(valid_array[...])
    assert np.array_equal(stored[0], valid) and stored[1].all()


def test_negative_radiance_is_one_warning_per_node_and_quiet_under_q(tmp_path):
    """Many poses with negative pixels: ``sbrdf run`` prints one summary line for the node (how many poses, the
    worst), not a line per pose; ``-q`` prints none; the counts stay on the CaptureSet either way."""
    rng = np.random.default_rng(5)
    images = []
    for i in range(6):
        img = (0.5 + 0.4 * rng.random((12, 16, 3))).astype(np.float32)
        if i != 2:  # five poses with 1 + i negative pixels each: pose 5 the worst
            img[4, : 1 + i, 0] = -0.3
        images.append(img)
    folder = _float_folder(tmp_path / "scan", images)

    def run(*flags, store):
        graph = tmp_path / f"{store}.yaml"
        graph.write_text(f"name: neg\nstore: {tmp_path / store}\nnodes:\n"
                         f"  capture: {{kind: Capture, plugin: folder, params: {{path: {folder}}}}}\n")
        proc = subprocess.run([sys.executable, "-m", "sbrdf_core.cli", "run", *flags, str(graph)], capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        return proc.stderr

    err = run("--scheduler", "sync", store="loud")
    lines = [line for line in err.splitlines() if "negative radiance" in line]
    assert len(lines) == 1, err
    assert "capture node 'capture'" in lines[0] and "5 of 6 poses have pixels with negative radiance" in lines[0]
    assert "worst poses[5] (id 5): 6 pixels" in lines[0] and "p00005_e0.exr" in lines[0]
    assert "negative radiance" not in run("-q", store="quiet")

    import zarr

    for store in ("loud", "quiet"):
        attrs = zarr.open_group(str(tmp_path / store / "capture"), mode="r").attrs
        assert attrs["negative_radiance_pixels"] == {"0": 1, "1": 2, "3": 4, "4": 5, "5": 6}


def test_a_pose_read_while_another_is_read_keeps_its_own_noise_tolerance(registry, tmp_path, monkeypatch):
    """Dask threads read poses of one capture at once: one read must not change another's tolerance.

    The tolerance of a float pose is 1 % of its own largest value; it was taken from state the
    reader shared across poses, so a read of another pose starting in between (here: made to
    happen, and to fail after it began) gave the first pose the tolerance of integer codes, and the
    validity mask of a capture depended on thread timing (seen as Register results that differed
    from run to run).
    """
    import sbrdf_capture.folder as folder_mod

    rng = np.random.default_rng(4)
    img = (50.0 + 40.0 * rng.random((12, 16, 3))).astype(np.float32)  # full scale ≈ 90: tolerance ≈ 0.9
    img[2, 2:6] = -0.5  # noise within the tolerance: kept
    folder = _float_folder(tmp_path / "scan", [img, img.copy()])
    src = registry.create("capture", "folder", {"path": str(folder)})
    src.describe()
    _, alone = src.read_pose(0)
    assert alone[2, 2:6].all()

    real_read, real_subtract = folder_mod.read_image, folder_mod.subtract_dark

    def interrupted(*args, **kwargs):
        raise OSError("read interrupted")

    def meanwhile(*args, **kwargs):  # pose 0 is between reading its image and judging its negatives
        monkeypatch.setattr(folder_mod, "read_image", interrupted)
        with pytest.raises(OSError):
            src.read_pose(1)
        monkeypatch.setattr(folder_mod, "read_image", real_read)
        return real_subtract(*args, **kwargs)

    monkeypatch.setattr(folder_mod, "subtract_dark", meanwhile)
    _, again = src.read_pose(0)
    assert np.array_equal(again, alone)


@pytest.mark.parametrize("white_level", [1.0, None], ids=["white-level", "no-white-level"])
def test_a_pose_whose_every_pixel_is_negative_is_an_error_naming_pose_and_file(registry, tmp_path, white_level):
    good = np.full((12, 16, 3), 0.4, np.float32)
    flipped = -np.linspace(0.1, 0.9, 12 * 16 * 3, dtype=np.float32).reshape(12, 16, 3)  # a sign-flipped image
    folder = _float_folder(tmp_path / "scan", [good, flipped], white_level=white_level)
    src = registry.create("capture", "folder", {"path": str(folder)})
    src.describe()
    src.read_pose(0)
    with pytest.raises(CaptureFolderError, match=r"capture.json: poses\[1\] \(id 1\): 192 of 192 pixels \(100.0%\) have "
                                                 r"negative radiance .* in images/p00001_e0.exr"):
        src.read_pose(1)
    from sbrdf_core.runner import run_graph

    graph = tmp_path / "g.yaml"
    graph.write_text(f"name: neg\nstore: {tmp_path / 'store'}\nnodes:\n"
                     f"  capture: {{kind: Capture, plugin: folder, params: {{path: {folder}}}}}\n")
    with pytest.raises(Exception, match=r"poses\[1\] \(id 1\): 192 of 192 pixels"):
        run_graph(str(graph))


def test_capture_modules_use_the_library_layer():
    """The format is in sbrdf_lib (writers in other packages share it); the capture plugins use those objects."""
    import sbrdf_capture.folder as folder
    import sbrdf_capture.response as response
    import sbrdf_capture.synthetic as synthetic
    import sbrdf_lib.capture_folder as lib
    import sbrdf_lib.patterns
    import sbrdf_lib.response

    assert folder.manifest_sections is lib.manifest_sections and folder.read_image is lib.read_image
    assert response.ResponseCurve is sbrdf_lib.response.ResponseCurve
    assert synthetic.pattern is sbrdf_lib.patterns.pattern
