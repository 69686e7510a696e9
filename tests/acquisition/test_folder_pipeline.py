"""A capture folder through the Capture node (one-node graph run by the runner)."""

from __future__ import annotations

import numpy as np
import zarr

from sbrdf_capture.photograph import capture_to_folder, orbit_poses
from sbrdf_core.runner import run_graph


def test_capture_node_reads_a_virtual_capture(registry, tmp_path):
    cam = registry.create("device", "virtual-camera", {"width": 128, "height": 96, "focal_px": 170.0, "texels": [32, 32],
                                                       "effects": ["falloff", "vignetting", "saturation"],
                                                       "intensity": 1.5e6})
    cam.bind(registry)
    light, R, t = orbit_poses(5)
    capture_to_folder(cam, tmp_path / "scan", light, R, t, [[0.5]] * 5, durable=False)
    graph = tmp_path / "g.yaml"
    graph.write_text(f"name: folder\nstore: {tmp_path / 'store'}\nnodes:\n"
                     f"  capture: {{kind: Capture, plugin: folder, params: {{path: {tmp_path / 'scan'}}}}}\n")
    report = run_graph(str(graph))
    assert report["capture"].status == "computed"
    g = zarr.open_group(str(tmp_path / "store" / "capture"), mode="r")
    images, valid = g["images"][...], g["valid"][...]
    assert images.shape == (5, 96, 128, 3) and g.attrs["camera"]["model"] == "pinhole"
    np.testing.assert_allclose(g["light_pos"][...], light)
    np.testing.assert_allclose(g["camera_R"][...], R)
    saturated = 0
    for i in range(5):
        truth = cam.sensor_radiance(light[i], R[i], t[i], i)
        v = valid[i]
        np.testing.assert_allclose(images[i][v], truth[v], rtol=1e-6, atol=1e-9)
        saturated += int((~v & (truth.max(axis=-1) * 0.5 >= 0.98)).sum())
        assert not v[truth.max(axis=-1) * 0.5 >= 0.98].any()
    assert valid.any() and saturated > 0
    assert run_graph(str(graph))["capture"].status == "cached"
