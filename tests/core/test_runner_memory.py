"""Per-pose tasks carry O(1) bytes: what keeps a distributed run's memory flat in the scan's size.

A node argument holding something per pose (a capture source's manifest, a
Registration's per-pose geometry, every pose's light position) must reach the
graph as one key, not as a literal copied into every pose's task.  On a
``distributed`` cluster each task's spec is pickled and unpickled on its own, so
such a copy costs O(poses) bytes per task and a worker holding its queued tasks
O(poses²): measured before the fix, peak worker RSS of Register + Reflectance
grew 0.25 → 1 GB from ~180 to ~350 MB per worker (``benchmarks/reflectance.py``,
docs/registration.md).  The invariant checked here is the graph property behind
it, on real capture folders (virtual camera), real aruco, zarr and the Runner:
going from 4 to 12 poses, no kind of task that occurs more than once grows.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import cloudpickle
import pytest
from dask.callbacks import Callback
from dask.utils import key_split

from sbrdf_capture.photograph import capture_to_folder, orbit_poses
from sbrdf_core.graph import load_graph
from sbrdf_core.runner import Runner
from sbrdf_core.streaming import Subgraph


class TaskSizes(Callback):
    """Per kind of computation (dask's ``key_split``): how many ran and the largest pickled spec.

    Data keys (a ``from_array`` chunk, a ``delayed`` object) are skipped: each is one
    key, however large, fetched once per worker by the tasks that depend on it.
    """

    def __init__(self):
        super().__init__()
        self.count: dict[str, int] = defaultdict(int)
        self.largest: dict[str, int] = defaultdict(int)
        self.names: set[str] = set()  # the key names themselves (a tuple key's name part)

    def _start(self, dsk):
        for key, task in dsk.items():
            if not callable(getattr(task, "func", None)):
                continue
            kind = key_split(key)
            self.names.add(key[0] if isinstance(key, tuple) else key)
            self.count[kind] += 1
            self.largest[kind] = max(self.largest[kind], len(cloudpickle.dumps(task)))
            for arg in getattr(task, "args", ()):  # a streamed node's fused chunk group: count its tasks too
                if isinstance(getattr(arg, "value", arg), Subgraph):
                    self._start(getattr(arg, "value", arg).graph)


def task_sizes(registry, tmp_path: Path, poses: int) -> TaskSizes:
    cam = registry.create("device", "virtual-camera", {"width": 320, "height": 240, "focal_px": 560.0, "texels": [32, 32],
                                                       "model": "lambert", "intensity": 1.5e5, "motor_light_mm": 0.0,
                                                       "seed": 7})
    cam.bind(registry)
    folder = tmp_path / f"scan-{poses}"
    light, R, t = orbit_poses(poses, max_camera_theta_deg=40.0)
    capture_to_folder(cam, folder, light, R, t, [[1.0]] * poses, durable=False)
    g = tmp_path / f"g{poses}.yaml"
    g.write_text(f"""name: sizes
store: {tmp_path / f'store-{poses}'}
nodes:
  capture: {{kind: Capture, plugin: folder, params: {{path: '{folder}'}}}}
  register: {{kind: Register, plugin: aruco, in: {{capture: capture}}, params: {{texels: [160, 160]}}}}
  reflectance: {{kind: Reflectance, in: {{stack: register}}}}
""")
    runner = Runner(registry)
    with TaskSizes() as sizes:
        runner.run(load_graph(str(g), registry))
    return sizes


@pytest.fixture(scope="module")
def sizes(registry, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("task-sizes")
    return task_sizes(registry, tmp, 4), task_sizes(registry, tmp, 12)  # 160² texels: 4 tiles of 128² (and edges)


def test_per_pose_tasks_do_not_grow_with_the_number_of_poses(sizes):
    few, many = sizes
    assert many.count["capture-read-capture"] == 12 and few.count["capture-read-capture"] == 4
    # Register: one task per pose block (pose_block: ≥ 8 blocks, so one pose a block at 4 and 12 poses)
    assert few.count["register-resample-register"] == 4 and many.count["register-resample-register"] == 12
    repeated = [k for k, n in few.count.items() if n > 1 and many.count.get(k, 0) > 1]
    assert {"capture-read-capture", "register-resample-register", "reflectance-reflectance"} <= set(repeated)
    # Key names get a digit or two longer; 8 more poses of anything per-pose (a manifest
    # entry, a homography, a light position: ≥ 24 bytes each) would add far more.
    grown = {k: (few.largest[k], many.largest[k]) for k in repeated if many.largest[k] > few.largest[k] + 64}
    assert not grown, f"tasks whose spec grows with the number of poses (bytes at 4 → 12 poses): {grown}"


def test_task_keys_name_their_artifact(sizes):
    """Key names carry a hash of the artifact (``BuildContext.key``): two runs of one graph into two stores, as a
    batch of scans on one cluster makes, share no key, while ``key_split`` still counts them by node."""
    import re

    few, many = sizes
    for prefix in ("capture-read-capture", "register-resample-register", "reflectance-reflectance"):
        a = {n for n in few.names if n.startswith(prefix + "-")}
        b = {n for n in many.names if n.startswith(prefix + "-")}
        assert len(a) == 1 and len(b) == 1 and a != b, (prefix, a, b)
        assert re.fullmatch(re.escape(prefix) + r"-[0-9a-f]{8}", a.pop())
