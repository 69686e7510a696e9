"""Capture folders against hostile or unlucky input: foreign folders, nested images, decompression bombs,
sign-flipped radiance.  Cases outside the store check a sentinel folder: its full listing and every file's
bytes must be unchanged afterwards."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sbrdf_lib.capture_folder import CaptureFolderError
from tests.acquisition.test_virtual_folder import params
from tests.plugins.test_output_confinement import snapshot

# -- virtual-folder writes only into its own folders -------------------------------------------------------------


@pytest.mark.parametrize("content", ["user-files", "image-names", "images-only"])
def test_virtual_folder_leaves_a_folder_of_someone_elses_files_alone(tmp_path, registry, content):
    folder = tmp_path / "scan"
    (folder / "images").mkdir(parents=True)
    if content in ("user-files", "image-names"):
        (folder / "notes.txt").write_text("my measurements\n")
    if content in ("image-names", "images-only"):  # the very names the writer would use
        (folder / "images" / "p00000_e0.png").write_bytes(b"not yours" * 100)
    before = snapshot(folder)
    source = registry.create("capture", "virtual-folder", params(folder))
    source.bind(registry)
    with pytest.raises(CaptureFolderError) as e:
        source.describe()
    assert str(folder) in str(e.value) and "left alone" in str(e.value) and "capture.json" in str(e.value)
    assert snapshot(folder) == before


def test_virtual_folder_refuses_a_file_as_its_folder(tmp_path, registry):
    f = tmp_path / "scan"
    f.write_text("a file")
    source = registry.create("capture", "virtual-folder", params(f))
    source.bind(registry)
    with pytest.raises(CaptureFolderError, match="is a file, not a folder"):
        source.describe()
    assert f.read_text() == "a file"


def test_virtual_folder_writes_into_an_empty_folder_and_resumes_its_own(tmp_path, registry):
    folder = tmp_path / "scan"
    (folder / "images").mkdir(parents=True)  # what a run killed before its manifest leaves
    source = registry.create("capture", "virtual-folder", params(folder))
    source.bind(registry)
    assert source.describe().n_poses == 3 and source.rendered == 3
    again = registry.create("capture", "virtual-folder", params(folder))
    again.bind(registry)
    assert again.describe().n_poses == 3 and again.rendered == 0


# -- the cache fingerprint covers every file a capture reads ------------------------------------------------------


def nested_folder(tmp_path, registry) -> Path:
    """A small complete capture whose manifest names its images in subfolders of images/."""
    import json

    from sbrdf_capture.photograph import capture_to_folder, orbit_poses

    cam = registry.create("device", "virtual-camera", {"width": 96, "height": 72, "focal_px": 130.0,
                                                       "texels": [8, 8]})
    cam.bind(registry)
    folder = tmp_path / "scan"
    light, R, t = orbit_poses(3)
    capture_to_folder(cam, folder, light, R, t, 1.0, durable=False)
    doc = json.loads((folder / "capture.json").read_text())
    for pose in doc["poses"]:
        for e in pose["exposures"]:
            new = f"images/pose{pose['id']}/deeper/{Path(e['file']).name}"
            (folder / new).parent.mkdir(parents=True)
            (folder / e["file"]).rename(folder / new)
            e["file"] = new
    (folder / "capture.json").write_text(json.dumps(doc))
    return folder


def test_replacing_an_image_in_a_subfolder_recomputes_the_capture(tmp_path, registry):
    import numpy as np
    import yaml

    from sbrdf_core.runner import run_graph
    from sbrdf_core.store import open_artifact
    from sbrdf_lib.capture_folder import encode_image, read_image

    folder = nested_folder(tmp_path, registry)
    g = tmp_path / "g.yaml"
    g.write_text(yaml.safe_dump({"name": "nested", "store": str(tmp_path / "store"), "nodes": {
        "capture": {"kind": "Capture", "plugin": "folder", "params": {"path": str(folder), "response": "linear"}}}}))
    assert [n.status for n in run_graph(str(g)).nodes] == ["computed"]
    first = open_artifact(str(tmp_path / "store" / "capture")).read("images")[1]

    (image,) = (folder / "images" / "pose1" / "deeper").iterdir()
    pixels = read_image(image, "test")
    stat = image.stat()
    image.write_bytes(encode_image((pixels / 2).astype(pixels.dtype), image.suffix))
    os.utime(image, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))  # a replacement: a new mtime
    rep = run_graph(str(g))
    assert [n.status for n in rep.nodes] == ["computed"]
    second = open_artifact(str(tmp_path / "store" / "capture")).read("images")[1]
    assert not np.allclose(first, second)
    assert [n.status for n in run_graph(str(g)).nodes] == ["cached"]


def test_the_fingerprint_sees_files_named_anywhere_in_the_folder_and_the_journal(tmp_path, registry):
    import json

    folder = nested_folder(tmp_path, registry)
    doc = json.loads((folder / "capture.json").read_text())
    outside_images = "raw/p0.png"  # a manifest may name an image outside images/ (still inside the folder)
    (folder / "raw").mkdir()
    (folder / doc["poses"][0]["exposures"][0]["file"]).rename(folder / outside_images)
    doc["poses"][0]["exposures"][0]["file"] = outside_images
    (folder / "capture.json").write_text(json.dumps(doc))
    src = registry.create("capture", "folder", {"path": str(folder)})
    before = src.fingerprint()
    st = (folder / outside_images).stat()
    os.utime(folder / outside_images, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    assert src.fingerprint() != before
    before = src.fingerprint()
    (folder / "capture.journal").write_text('{"id": 9}\n')
    assert src.fingerprint() != before


# -- a decompression bomb fails at once -------------------------------------------------------------------------


def png_bomb(path: Path, side: int) -> None:
    """An 8-bit grey PNG of ``side`` x ``side`` zero pixels: a few hundred kB that inflate to side² bytes."""
    import zlib

    comp = zlib.compressobj(1)
    row = b"\x00" * (side + 1)
    data = b"".join(comp.compress(row) for _ in range(side)) + comp.flush()

    def chunk(kind: bytes, body: bytes) -> bytes:
        return len(body).to_bytes(4, "big") + kind + body + zlib.crc32(kind + body).to_bytes(4, "big")

    ihdr = side.to_bytes(4, "big") + side.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", data) + chunk(b"IEND", b""))


def png_folder(tmp_path, registry) -> Path:
    from sbrdf_capture.photograph import capture_to_folder, orbit_poses

    cam = registry.create("device", "virtual-camera", {"width": 96, "height": 72, "focal_px": 130.0,
                                                       "texels": [8, 8], "effects": ["response", "falloff"]})
    cam.bind(registry)
    light, R, t = orbit_poses(3)
    folder = tmp_path / "scan"
    capture_to_folder(cam, folder, light, R, t, [[0.5, 2.0]] * 3, durable=False)
    return folder


def test_a_decompression_bomb_png_fails_at_once_naming_it(tmp_path, registry):
    import time

    import yaml

    from sbrdf_core.errors import SbrdfError
    from sbrdf_core.runner import run_graph

    folder = png_folder(tmp_path, registry)
    source = registry.create("capture", "folder", {"path": str(folder)})
    source.describe()  # the folder was fine when described; the bomb arrives before the pose is read
    bomb = folder / "images" / "p00001_e1.png"
    png_bomb(bomb, 20000)
    t0 = time.perf_counter()
    with pytest.raises(CaptureFolderError) as e:
        source.read_pose(1)
    assert time.perf_counter() - t0 < 2.0  # decoding it takes seconds and 400 MB
    assert str(bomb) in str(e.value) and "20000x20000" in str(e.value) and "not decoded" in str(e.value)

    g = tmp_path / "g.yaml"
    g.write_text(yaml.safe_dump({"name": "bomb", "store": str(tmp_path / "store"), "nodes": {
        "capture": {"kind": "Capture", "plugin": "folder", "params": {"path": str(folder)}}}}))
    t0 = time.perf_counter()
    with pytest.raises(SbrdfError, match="20000x20000"):
        run_graph(str(g))
    assert time.perf_counter() - t0 < 20.0


def test_an_exr_header_claiming_too_many_pixels_is_not_decoded(tmp_path):
    import numpy as np

    from sbrdf_core.io.images import read_exr, write_exr

    path = tmp_path / "big.exr"
    write_exr(str(path), np.zeros((64, 64, 3), np.float32))
    with pytest.raises(ValueError, match=r"64x64 pixels, more than the 1000 .*not decoded"):
        read_exr(str(path), max_pixels=1000)
    assert read_exr(str(path)).shape == (64, 64, 3)


# -- a sign-flipped image on a dark background is an error -------------------------------------------------------


def dark_background_pose(rng, flipped: bool, noise: float = 0.002):
    """48 x 64 pixels of zero-mean background noise with a lit square covering 12 % of the image."""
    import numpy as np

    img = rng.normal(0.0, noise, (48, 64, 3))
    img[18:30, 22:46] += 0.2 + 0.7 * rng.random((12, 24, 3))
    return (-img if flipped else img).astype(np.float32)


@pytest.mark.parametrize("white_level", [None, 1.0], ids=["no-white-level", "white-level"])
def test_a_sign_flipped_exr_with_a_dark_background_is_an_error_naming_it(registry, tmp_path, white_level):
    import numpy as np

    from tests.acquisition.test_folder_format import _float_folder

    rng = np.random.default_rng(7)
    poses = [dark_background_pose(rng, False), dark_background_pose(rng, True)]
    if white_level is not None:  # pure noise under a known full scale: symmetric, never a majority above the floor
        poses.append(rng.normal(0.0, 0.002, (48, 64, 3)).astype(np.float32))
    folder = _float_folder(tmp_path / "scan", poses, white_level=white_level)
    src = registry.create("capture", "folder", {"path": str(folder)})
    src.describe()
    src.read_pose(0)
    if white_level is not None:
        src.read_pose(2)
    with pytest.raises(CaptureFolderError, match=r"poses\[1\] \(id 1\): 288 of the 288 pixels above the noise floor "
                                                 r".* have negative radiance .* in images/p00001_e0.exr"):
        src.read_pose(1)
