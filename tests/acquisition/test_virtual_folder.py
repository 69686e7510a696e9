"""The ``virtual-folder`` capture source: a graph that makes its own capture folder (issue 23).

Small images and few poses so every test takes about a second; the whole
``graphs/virtual-scan.yaml`` pipeline is in tests/plugins/test_aruco.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from sbrdf_core.runner import run_graph
from sbrdf_core.store import open_artifact
from sbrdf_lib.capture_folder import CaptureFolderError

CAMERA = {"width": 96, "height": 72, "focal_px": 160.0, "texels": [8, 8], "intensity": 1.5e5,
          "effects": ["falloff", "motor_error"], "carrier_supersample": 1, "seed": 3}


def params(folder: Path, **over) -> dict:
    p = {"path": str(folder), "camera": {"device": "virtual-camera", "params": dict(CAMERA)}, "poses": 3,
         "exposures": [0.5, 1.0], "durable": False}
    p.update(over)
    return p


def graph(tmp_path: Path, **over) -> Path:
    g = tmp_path / "g.yaml"
    g.write_text(yaml.safe_dump({"name": "vf", "store": str(tmp_path / "store"), "nodes": {
        "capture": {"kind": "Capture", "plugin": "virtual-folder", "params": params(tmp_path / "scan", **over)}}}))
    return g


def status(report) -> list[str]:
    return [n.status for n in report.nodes]


def test_graph_makes_its_folder_and_reads_it_as_folder_does(tmp_path, registry):
    rep = run_graph(str(graph(tmp_path)))
    assert status(rep) == ["computed"]
    folder = tmp_path / "scan"
    manifest = json.loads((folder / "capture.json").read_text())
    assert manifest["format"] == "sbrdf-capture/1" and manifest["complete"] and len(manifest["poses"]) == 3
    assert manifest["rig"]["source"] == "virtual-folder" and manifest["rig"]["exposures"] == [0.5, 1.0]
    assert [len(p["exposures"]) for p in manifest["poses"]] == [2, 2, 2]
    # The stored CaptureSet is exactly what the folder plugin makes of the same folder.
    art = open_artifact(str(tmp_path / "store" / "capture"))
    reader = registry.create("capture", "folder", {"path": str(folder)})
    desc = reader.describe()
    np.testing.assert_allclose(art.read("light_pos"), desc.light_pos)
    np.testing.assert_allclose(art.read("camera_t"), desc.camera_t)
    np.testing.assert_allclose(art.read("exposure_s"), desc.exposure_s)
    assert art.attrs["sample"] == desc.sample
    for i in range(3):
        image, valid = reader.read_pose(i)
        np.testing.assert_array_equal(art.read("images")[i], np.where(np.isfinite(image), image, 0))
        np.testing.assert_array_equal(art.read("valid")[i], valid)


def test_rerun_is_cached_and_a_lost_store_reuses_the_folder(tmp_path):
    g = graph(tmp_path)
    run_graph(str(g))
    manifest = tmp_path / "scan" / "capture.json"
    stamp = manifest.stat().st_mtime_ns
    assert status(run_graph(str(g))) == ["cached"]
    import shutil

    shutil.rmtree(tmp_path / "store")
    from sbrdf_core.registry import default_registry

    reg = default_registry()
    source = reg.create("capture", "virtual-folder", params(tmp_path / "scan"))
    source.bind(reg)
    assert source.describe().n_poses == 3 and source.rendered == 0  # the complete folder is read, not re-rendered
    assert status(run_graph(str(g))) == ["computed"]
    assert manifest.stat().st_mtime_ns == stamp


def test_changed_parameters_rerender_the_folder(tmp_path):
    run_graph(str(graph(tmp_path)))
    rep = run_graph(str(graph(tmp_path, poses=4, exposures=[1.0])))  # 3 poses of 2 exposures -> 4 of 1
    assert status(rep) == ["computed"]
    manifest = json.loads((tmp_path / "scan" / "capture.json").read_text())
    assert len(manifest["poses"]) == 4 and manifest["rig"]["poses"] == 4
    assert sorted(f.name for f in (tmp_path / "scan" / "images").iterdir()) == [f"p{i:05d}_e0.exr" for i in range(4)]
    assert all(len(p["exposures"]) == 1 for p in manifest["poses"])
    assert open_artifact(str(tmp_path / "store" / "capture")).read("images").shape[0] == 4


def test_an_interrupted_render_resumes(tmp_path, registry):
    source = registry.create("capture", "virtual-folder", params(tmp_path / "scan"))
    source.bind(registry)
    real, calls = source.camera.photograph, []

    def failing(*a, **k):
        calls.append(1)
        if len(calls) > 2:  # two exposures = the first pose
            raise KeyboardInterrupt
        return real(*a, **k)

    source.camera.photograph = failing
    with pytest.raises(KeyboardInterrupt):
        source.describe()
    assert not json.loads((tmp_path / "scan" / "capture.json").read_text())["complete"]
    again = registry.create("capture", "virtual-folder", params(tmp_path / "scan"))
    again.bind(registry)
    assert again.describe().n_poses == 3 and again.rendered == 2  # pose 0 came from the journal


def test_a_folder_it_did_not_write_is_left_alone(tmp_path, registry):
    from sbrdf_capture.photograph import capture_to_folder, orbit_poses

    cam = registry.create("device", "virtual-camera", CAMERA)
    cam.bind(registry)
    light, R, t = orbit_poses(2)
    capture_to_folder(cam, tmp_path / "scan", light, R, t, [1.0, 1.0], durable=False)
    before = (tmp_path / "scan" / "capture.json").read_text()
    source = registry.create("capture", "virtual-folder", params(tmp_path / "scan"))
    source.bind(registry)
    with pytest.raises(CaptureFolderError, match="did not write"):
        source.describe()
    assert (tmp_path / "scan" / "capture.json").read_text() == before


def test_bad_exposures_are_refused(registry):
    from sbrdf_core.errors import ParameterError

    with pytest.raises(ParameterError, match="exposures"):
        registry.create("capture", "virtual-folder", params(Path("x"), exposures=[[1.0], [2.0]]))
    with pytest.raises(ParameterError, match="bracket"):
        registry.create("capture", "virtual-folder", params(Path("x"), exposures=[0.1, 0.2, 0.4, 0.8]))
