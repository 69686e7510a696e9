"""Capture folders against hostile or unlucky input: foreign folders, nested images, decompression bombs,
sign-flipped radiance.  Cases outside the store check a sentinel folder: its full listing and every file's
bytes must be unchanged afterwards."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sbrdf_lib.capture_folder import CaptureFolderError
from tests.acquisition.test_virtual_folder import params


def snapshot(root: Path) -> dict[str, bytes | str]:
    out: dict[str, bytes | str] = {}
    for dirpath, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(dirpath) / name
            rel = str(p.relative_to(root))
            out[rel] = ("link:" + os.readlink(p)) if p.is_symlink() else "dir" if p.is_dir() else p.read_bytes()
    return out


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
