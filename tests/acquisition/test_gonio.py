"""The ``gonio`` capture source end to end: pty simulators + real drivers + virtual camera + folders + the runner.

Nothing is mocked: the motors are the production drivers talking to the
protocol simulators over pseudo-terminals, the camera is the virtual camera,
the folder is written by ``CaptureFolderWriter`` and read back through the
``folder`` plugin's code, and every capture runs as a one-node YAML graph
through :func:`sbrdf_core.runner.run_graph` (or the ``sbrdf`` CLI in a
subprocess that gets SIGKILLed).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zarr

from sbrdf_capture.gonio import GonioCaptureError
from sbrdf_core.errors import ArtifactError, ParameterError
from sbrdf_core.graph import load_graph
from sbrdf_core.runner import run_graph
from sbrdf_core.store import open_artifact
from sbrdf_devices.motors.sim import Fault, SimulatedIndexer, SimulatedPTU
from sbrdf_lib.capture_folder import JOURNAL, MANIFEST, load_manifest, read_journal
from sbrdf_lib.rig_geometry import RigGeometry, forward
from sbrdf_lib.serial.errors import LinkLost, PositionError, ReplyTimeout, SoftLimitError

from ..conftest import assert_stores_equal

REPO = Path(__file__).resolve().parents[2]

#: [pan, tilt, roll, light] per pose: inside the PTU-46 ranges (tilt -47..31) and the light arm's 10..175.
#: Every pose keeps the light above the sample plane (z > 0): a light at or below it is refused (issue 21).
ANGLES = [[0.0, 0.0, 0.0, 30.0], [10.0, -10.0, 20.0, 45.0], [20.0, -20.0, 40.0, 60.0], [-10.0, 10.0, -30.0, 60.0],
          [30.0, -30.0, 90.0, 70.0], [5.0, 5.0, -90.0, 20.0], [-25.0, 25.0, 150.0, 40.0], [15.0, -40.0, -150.0, 50.0]]
CAMERA = {"device": "virtual-camera",
          "params": {"width": 48, "height": 36, "focal_px": 180.0, "texels": [12, 12], "intensity": 4000000.0,
                     "effects": ["falloff", "saturation", "response", "noise"], "seed": 7}}


def motors(pan="sim", tilt_roll="sim", light="sim", timeout_s=1.0) -> dict:
    """McAllister's arrangement: one PTU pans, a second tilts and rolls, an indexer swings the light."""
    link = {"timeout_s": timeout_s, "retries": 2}
    return {"sample_pan": {"device": "ptu", "params": {"port": pan, **link}, "axes": {"pan": "pan_deg"}},
            "sample_tilt_roll": {"device": "ptu", "params": {"port": tilt_roll, **link},
                                 "axes": {"tilt": "tilt_deg", "roll": "pan_deg"}},
            "light_arm": {"device": "indexer", "params": {"port": light, **link}, "axes": {"light": "angle_deg"}}}


def write_graph(tmp_path: Path, name: str, n_poses: int = 6, **params) -> tuple[Path, Path, Path]:
    """A one-node graph capturing with gonio; returns (graph file, store, capture folder)."""
    store, folder = tmp_path / f"{name}-store", tmp_path / f"{name}-scan"
    p = {"path": str(folder), "motors": motors(), "camera": CAMERA, "plan": {"angles_deg": ANGLES[:n_poses]},
         "exposures": {"times_s": [0.25, 1.0]}, "durable": False, **params}
    graph = tmp_path / f"{name}.yaml"
    graph.write_text(json.dumps({"name": name, "store": str(store),
                                 "nodes": {"capture": {"kind": "Capture", "plugin": "gonio", "params": p}}}, indent=1))
    return graph, store, folder


def rig_sims(start_simulator, **faults) -> dict:
    """Simulators for the three motors, started by the test (so it can inject faults and inspect them)."""
    return {"pan": start_simulator(SimulatedPTU, faults=faults.get("pan", [])),
            "tilt_roll": start_simulator(SimulatedPTU, faults=faults.get("tilt_roll", [])),
            "light": start_simulator(SimulatedIndexer, faults=faults.get("light", []))}


def ports(sims: dict, timeout_s: float = 1.0) -> dict:
    return motors(sims["pan"].port, sims["tilt_roll"].port, sims["light"].port, timeout_s=timeout_s)


def folder_files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def capture_arrays(store: Path) -> dict[str, np.ndarray]:
    g = zarr.open_group(str(store / "capture"), mode="r")
    return {k: g[k][...] for k in ("images", "valid", "light_pos", "camera_R", "camera_t", "exposure_s")}


def assert_same_capture(a: Path, b: Path) -> None:
    A, B = capture_arrays(a), capture_arrays(b)
    for k in A:
        assert np.array_equal(A[k], B[k]), f"CaptureSet {k} differs"


# -- normal operation -------------------------------------------------------------------------------------------


def test_uninterrupted_capture_gives_complete_folder_and_captureset(tmp_path, start_simulator, registry):
    sims = rig_sims(start_simulator)
    graph, store, folder = write_graph(tmp_path, "clean", motors=ports(sims))
    rep = run_graph(str(graph))
    assert rep["capture"].status == "computed"

    m = load_manifest(folder)
    assert m.complete and [p.id for p in m.poses] == list(range(6)) and not (folder / JOURNAL).exists()
    assert sorted(os.listdir(folder / "images")) == [f"p{i:05d}_e{k}.png" for i in range(6) for k in range(2)]
    assert m.extra["rig"]["motors"]["light_arm"] == {"device": "indexer", "axes": {"light": "angle_deg"}}
    quantised = 0
    for pose, target in zip(m.poses, ANGLES):
        motors_ = pose.extra["motors"]
        assert [motors_["target_deg"][j] for j in ("pan", "tilt", "roll", "light")] == target
        # the recorded pose is the read-back one: within the drivers' tolerance of the target, on the step grid
        read = [motors_["read_deg"][j] for j in ("pan", "tilt", "roll", "light")]
        assert np.allclose(read, target, atol=0.05)
        quantised += read != target
        at = forward(RigGeometry(), *read)
        np.testing.assert_allclose(pose.light_pos_mm, at.light_pos_mm[0])
        np.testing.assert_allclose(pose.R, at.camera_R[0])
        assert [e.time_s for e in pose.exposures] == [0.25, 1.0]
    assert quantised >= 4
    # the motors ended at the last pose (roll rides on the second PTU's pan axis)
    assert sims["pan"].position_deg("pan") == pytest.approx(ANGLES[5][0], abs=0.02)
    assert sims["tilt_roll"].position_deg("pan") == pytest.approx(ANGLES[5][2], abs=0.02)
    assert sims["light"].position_deg(1) == pytest.approx(ANGLES[5][3], abs=0.02)

    # the CaptureSet: nominal planned poses, images equal to reading the finished folder with the folder plugin
    cs = open_artifact(str(store / "capture"))
    assert cs.complete and cs.attrs["camera"]["model"] == "pinhole" and cs.attrs["camera"]["response"] == "table"
    arrays = capture_arrays(store)
    nominal = forward(RigGeometry(), *np.array(ANGLES[:6]).T)
    np.testing.assert_array_equal(arrays["light_pos"], nominal.light_pos_mm)
    np.testing.assert_array_equal(arrays["camera_R"], nominal.camera_R)
    np.testing.assert_array_equal(arrays["exposure_s"], [0.25] * 6)
    assert arrays["images"].shape == (6, 36, 48, 3)
    reader = registry.create("capture", "folder", {"path": str(folder)})
    for i in range(6):
        image, valid = reader.read_pose(i)
        np.testing.assert_array_equal(arrays["images"][i][valid], image[valid])
        np.testing.assert_array_equal(arrays["valid"][i], valid)
    assert 0.05 < arrays["valid"].mean() < 0.95  # the carrier is in view and lit, the background is dark

    # unchanged: cached, and nothing is sent to the motors
    sent = {k: len(s.received) for k, s in sims.items()}
    assert run_graph(str(graph))["capture"].status == "cached"
    assert sent == {k: len(s.received) for k, s in sims.items()}


def test_complete_folder_is_read_without_motion(tmp_path):
    import shutil

    graph, store, folder = write_graph(tmp_path, "again", n_poses=3)
    run_graph(str(graph))
    before = folder_files(folder)
    first = capture_arrays(store)
    # The store is lost but the folder is complete: the source reads the folder back and never connects
    # (a port that does not exist would fail at once).
    shutil.rmtree(store)
    graph2, _, _ = write_graph(tmp_path, "again", n_poses=3, motors=motors("/dev/no-such-port", "/dev/no-such-port"))
    assert run_graph(str(graph2))["capture"].status == "computed"
    assert folder_files(folder) == before
    again = capture_arrays(store)
    assert all(np.array_equal(first[k], again[k]) for k in first)


def test_response_recovered_from_brackets_waits_for_the_whole_scan(tmp_path, registry):
    """Without a response curve in the manifest, recovery samples brackets of the whole scan: the first pose is
    read back only once every pose is on disk, so the curve (and the CaptureSet) cannot depend on interruptions."""
    camera = {"device": "virtual-camera", "params": {**CAMERA["params"], "record_response": False,
                                                     "effects": ["falloff", "saturation", "response"]}}
    graph, store, folder = write_graph(tmp_path, "recover", n_poses=4, camera=camera,
                                       exposures={"times_s": [0.125, 0.5, 2.0]})
    run_graph(str(graph))
    # the finished capture.json was written before the CaptureSet's first image chunk
    first_chunk = min(f.stat().st_mtime_ns for f in (store / "capture" / "images").rglob("*") if f.is_file()
                      and f.name != "zarr.json")
    assert (folder / MANIFEST).stat().st_mtime_ns <= first_chunk
    assert "response" not in json.loads((folder / MANIFEST).read_text())["camera"]
    arrays = capture_arrays(store)
    reader = registry.create("capture", "folder", {"path": str(folder)})
    assert reader.describe().camera["response"] == "table" and reader.curve is not None  # recovered
    for i in range(4):
        image, valid = reader.read_pose(i)
        np.testing.assert_array_equal(arrays["valid"][i], valid)
        np.testing.assert_array_equal(arrays["images"][i][valid], image[valid])
    assert arrays["valid"].any()


@pytest.mark.parametrize("changed", ["plan", "camera"])
def test_folder_of_another_capture_is_refused(tmp_path, changed):
    graph, _, folder = write_graph(tmp_path, "one", n_poses=2)
    run_graph(str(graph))
    before = folder_files(folder)
    other = ({"plan": {"angles_deg": ANGLES[2:4]}} if changed == "plan"
             else {"camera": {**CAMERA, "params": {**CAMERA["params"], "seed": 8}}})
    graph2, _, _ = write_graph(tmp_path, "two", n_poses=2, path=str(folder), **other)
    with pytest.raises(ArtifactError, match="different (rig, plan|sample, camera)"):
        run_graph(str(graph2))
    assert folder_files(folder) == before


# -- interruption ------------------------------------------------------------------------------------------------


def test_capture_killed_mid_run_resumes_to_the_same_captureset(tmp_path):
    n = 8
    graph, store, folder = write_graph(tmp_path, "killed", n_poses=n, settle_s=0.15)
    proc = subprocess.Popen([sys.executable, "-m", "sbrdf_core.cli", "run", "-q", str(graph)], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(read_journal(folder)) < 3:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.01)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    journaled = {p.id for p in read_journal(folder)}
    assert 3 <= len(journaled) < n, "the capture was not interrupted mid-run"
    assert not load_manifest(folder).complete
    with pytest.raises(ArtifactError, match="incomplete"):
        open_artifact(str(store / "capture"))
    stamps = {f: (folder / "images" / f).stat().st_mtime_ns for f in os.listdir(folder / "images") if not f.startswith(".")}
    assert {int(f[1:6]) for f in stamps} >= journaled

    rep = run_graph(str(graph))
    assert rep["capture"].status == "resumed" and rep["capture"].chunks_resumed > 0
    # journaled poses were read back, not taken again
    for f in stamps:
        if int(f[1:6]) in journaled:
            assert (folder / "images" / f).stat().st_mtime_ns == stamps[f], f"{f} was re-taken"

    graph2, store2, folder2 = write_graph(tmp_path, "uninterrupted", n_poses=n)
    run_graph(str(graph2))
    assert_same_capture(store, store2)
    assert_stores_equal(store, store2)
    killed, clean = folder_files(folder), folder_files(folder2)
    assert sorted(killed) == sorted(clean)  # no image lost or duplicated, no temporary file left
    assert killed == clean  # byte for byte, capture.json included


# -- faults ------------------------------------------------------------------------------------------------------


def test_transient_motor_faults_are_retried_and_change_nothing(tmp_path, start_simulator):
    faults = {"pan": [Fault("drop", match="PP", times=1, skip=2)],
              "tilt_roll": [Fault("miss", match=r"TP-?\d+", times=1, skip=2, miss_deg=1.0),
                            Fault("garble", match="TP", times=1, skip=1)],
              "light": [Fault("stall", match=r"!1TPE", times=1, skip=3, stall_s=0.3)]}
    sims = rig_sims(start_simulator, **faults)
    graph, store, folder = write_graph(tmp_path, "faulty", n_poses=4, motors=ports(sims, timeout_s=0.15))
    run_graph(str(graph))
    for key, fs in faults.items():
        for f in fs:
            assert f.fired == 1, f"{key}: {f} never fired"

    graph2, store2, folder2 = write_graph(tmp_path, "calm", n_poses=4)
    run_graph(str(graph2))
    assert_same_capture(store, store2)
    assert folder_files(folder) == folder_files(folder2)


@pytest.mark.parametrize("kind", ["drop", "miss"])
def test_persistent_motor_fault_stops_with_pose_port_and_command(tmp_path, start_simulator, kind):
    sims = rig_sims(start_simulator)
    graph, store, folder = write_graph(tmp_path, "broken", n_poses=5, motors=ports(sims, timeout_s=0.15))
    victim, fault = (("light", Fault("drop", times=None)) if kind == "drop"
                     else ("tilt_roll", Fault("miss", match=r"TP-?\d+", times=None, miss_deg=1.0)))
    injected = []

    def progress(node, done, total):  # after pose 1 is stored, the motor breaks for good
        if len(read_journal(folder)) >= 2 and not injected:
            injected.append(sims[victim].add_fault(fault))

    with pytest.raises(GonioCaptureError) as info:
        run_graph(str(graph), progress=progress)
    e = info.value
    assert isinstance(e.cause, ReplyTimeout if kind == "drop" else PositionError)
    message = str(e)
    assert e.pose == 2 and "pose 2 of 5" in message
    assert e.port == sims[victim].port and sims[victim].port in message
    assert e.command and f"command {e.command!r}" in message
    assert e.motor == ("light_arm" if kind == "drop" else "sample_tilt_roll") and repr(e.motor) in message
    assert "holds the 2 completed poses" in message

    # no complete artifact; the folder holds exactly poses 0 and 1
    with pytest.raises(ArtifactError, match="incomplete"):
        open_artifact(str(store / "capture"))
    assert not load_manifest(folder).complete
    assert [p.id for p in read_journal(folder)] == [0, 1]
    assert sorted(os.listdir(folder / "images")) == [f"p{i:05d}_e{k}.png" for i in range(2) for k in range(2)]
    # every motor was halted (PTU "H", indexer "!S") after the fault
    for key, halt in (("pan", "H"), ("tilt_roll", "H"), ("light", "!S")):
        assert halt in sims[key].received[-3:], f"{key} not halted: {sims[key].received[-5:]}"

    # With the motor repaired (a fresh rig on new ports), re-running resumes the folder: poses 0 and 1 are
    # read back, not taken again, and the result is that of a capture that never failed.  (The new ports
    # change the node's parameters, so the CaptureSet itself is rebuilt - from the folder.)
    stamps = {f: (folder / "images" / f).stat().st_mtime_ns for f in os.listdir(folder / "images")}
    fresh = rig_sims(start_simulator)
    write_graph(tmp_path, "broken", n_poses=5, motors=ports(fresh))
    run_graph(str(graph))
    assert all((folder / "images" / f).stat().st_mtime_ns == t for f, t in stamps.items())
    graph2, store2, folder2 = write_graph(tmp_path, "whole", n_poses=5)
    run_graph(str(graph2))
    assert_same_capture(store, store2)
    assert folder_files(folder) == folder_files(folder2)


@pytest.mark.parametrize("victim", ["light", "tilt_roll"])
def test_a_device_vanishing_mid_capture_names_motor_port_command_and_pose(tmp_path, start_simulator, victim):
    """Issue 21: a serial adapter pulled out mid-capture was a bare ``termios.error`` naming nothing."""
    sims = rig_sims(start_simulator)
    graph, store, folder = write_graph(tmp_path, "unplugged", n_poses=5, motors=ports(sims, timeout_s=0.15))
    injected = []

    def progress(node, done, total):  # after pose 1 is stored, the victim's port disappears
        if len(read_journal(folder)) >= 2 and not injected:
            injected.append(sims[victim].add_fault(Fault("vanish", times=1)))

    with pytest.raises(GonioCaptureError) as info:
        run_graph(str(graph), progress=progress)
    e = info.value
    assert isinstance(e.cause, LinkLost) and sims[victim].unplugged
    message = str(e)
    motor = {"light": "light_arm", "tilt_roll": "sample_tilt_roll"}[victim]
    assert e.pose == 2 and "pose 2 of 5" in message
    assert e.motor == motor and repr(motor) in message
    assert e.port == sims[victim].port and sims[victim].port in message
    assert e.command and f"command {e.command!r}" in message
    assert "serial link lost" in message and "every other motor halted" in message
    assert "holds the 2 completed poses" in message
    with pytest.raises(ArtifactError, match="incomplete"):
        open_artifact(str(store / "capture"))
    assert [p.id for p in read_journal(folder)] == [0, 1]
    for key, halt in (("pan", "H"), ("tilt_roll", "H"), ("light", "!S")):
        if key != victim:
            assert halt in sims[key].received[-3:], f"{key} not halted: {sims[key].received[-5:]}"


def test_soft_limits_in_the_plan_are_refused_before_any_motion(tmp_path, start_simulator):
    sims = rig_sims(start_simulator)
    bad = ANGLES[:3] + [[0.0, 40.0, 0.0, 45.0]]  # tilt 40 deg: beyond the PTU-46's +31 deg
    graph, store, folder = write_graph(tmp_path, "limits", motors=ports(sims), plan={"angles_deg": bad})
    with pytest.raises(SoftLimitError) as info:
        run_graph(str(graph))
    message = str(info.value)
    assert "refused before any motion" in message and "pose 3" in message and "tilt = 40 deg" in message
    assert info.value.port == sims["tilt_roll"].port and message.startswith(f"ptu on {sims['tilt_roll'].port}: ")
    assert re.search(r"motor 'sample_tilt_roll' \(ptu on /dev/\S+\) tilt_deg soft limits \[-47, 30\.99\d*\] \(1 pose\)",
                     message), message
    moves = [c for s in sims.values() for c in s.received if re.fullmatch(r"[PT]P-?\d+|\d?D-?\d+|GO\d*", c)]
    assert moves == [], f"motion was commanded: {moves}"
    assert sims["light"].received and sims["pan"].received  # the drivers did connect (limits are the units')
    assert not (folder / MANIFEST).exists()
    with pytest.raises(ArtifactError):
        open_artifact(str(store / "capture"))
    assert [s.received[-1] for s in sims.values()] == ["H", "H", "!S"]  # halted and released


def test_a_plan_putting_the_light_below_the_sample_is_refused_before_connecting(tmp_path, start_simulator):
    sims = rig_sims(start_simulator)
    below = ANGLES[:2] + [[-10.0, 10.0, -30.0, 90.0], [30.0, -30.0, 90.0, 120.0]]  # light at z = -196 mm, -25 mm
    graph, store, folder = write_graph(tmp_path, "below", motors=ports(sims), plan={"angles_deg": below})
    with pytest.raises(ParameterError, match=r"2 of 4 poses put the light at or below the sample plane .* pose 2 "
                                             r"\[pan, tilt, roll, light\] = \[-10.0, 10.0, -30.0, 90.0\] deg puts it at "
                                             r"z = -196.4 mm \(poses \[2, 3\]\)"):
        run_graph(str(graph))
    assert all(not s.received for s in sims.values()), "nothing may even connect"
    assert not folder.exists()


def test_plan_outside_the_geometry_or_undriven_joints_is_refused(tmp_path):
    graph, _, folder = write_graph(tmp_path, "geo", geometry={"light_limits_deg": [40, 175]})
    with pytest.raises(SoftLimitError, match=r"pose 0: light = 30 deg is outside the rig geometry's light_limits_deg \[40, 175\]"):
        run_graph(str(graph))
    no_roll = motors()
    del no_roll["sample_tilt_roll"]["axes"]["roll"]
    graph, _, _ = write_graph(tmp_path, "noroll", motors=no_roll)
    with pytest.raises(SoftLimitError, match="pose 1: roll = 20 deg but no motor drives roll"):
        run_graph(str(graph))


def test_bad_configuration_is_reported_before_connecting(tmp_path):
    def err(**params):
        graph, _, _ = write_graph(tmp_path, "cfg", **params)
        with pytest.raises(Exception) as info:
            run_graph(str(graph))
        return str(info.value)

    m = motors()
    m["light_arm"]["axes"] = {"light": "tilt_deg"}
    assert "'indexer' has no axis ['tilt_deg']; its axes are ['angle_deg']" in err(motors=m)
    m = motors()
    m["light_arm"]["axes"] = {"tilt": "angle_deg"}
    assert "joint 'tilt' is driven by two motors" in err(motors=m)
    m = motors()
    m["light_arm"]["params"]["speed"] = 3
    assert "unknown parameter 'speed'" in err(motors=m)
    assert "either angles_deg" in err(plan={"angles_deg": ANGLES, "theta_d_deg": 10})
    assert "a bracket is 1 to 3 positive times" in err(exposures={"times_s": [0.1, 0.2, 0.4, 0.8]})


def test_exposure_planner_takes_max_exposures_as_a_count(tmp_path):
    """exposures.max_exposures reached the planner as a float (every planner key went through float()), and
    numpy refused it as an array size: any plan giving it failed.  It is a count; a fraction is refused."""
    from sbrdf_capture.gonio import GonioCapture

    planner = {"diffuse_time_s": 0.5, "highlight_time_s": 2.0 ** -7}

    def brackets(**exposures) -> list[list[float]]:
        source = GonioCapture(path=str(tmp_path / "scan"), motors=motors(), plan={"angles_deg": ANGLES},
                              exposures={**planner, **exposures})
        return source.planned()[1]

    assert max(len(b) for b in brackets()) >= 2  # the planner brackets some pose with its default of 3
    assert max(len(b) for b in brackets(max_exposures=1)) == 1
    assert brackets(max_exposures=3) == brackets() and brackets(max_exposures=3.0) == brackets()
    with pytest.raises(ParameterError, match="max_exposures: expected a whole number"):
        brackets(max_exposures=2.5)


# -- the shipped graph -------------------------------------------------------------------------------------------


def test_gonio_virtual_graph_runs_end_to_end(tmp_path, registry):
    """graphs/gonio-virtual.yaml validates and runs on the simulated rig (folder path redirected into tmp)."""
    import yaml

    source = REPO / "graphs" / "gonio-virtual.yaml"
    g = load_graph(str(source), registry)  # validates the shipped file as is
    assert g.nodes["capture"].plugin == "gonio"
    data = yaml.safe_load(source.read_text())
    params = data["nodes"]["capture"]["params"]
    assert all(m["params"]["port"] == "sim" for m in params["motors"].values())
    params["path"] = str(tmp_path / "scan")
    params["camera"]["params"].update(width=64, height=48, focal_px=250.0)  # small, so the test is fast
    data["store"] = str(tmp_path / "store")
    (tmp_path / "g.yaml").write_text(yaml.safe_dump(data))
    rep = run_graph(str(tmp_path / "g.yaml"))
    m = load_manifest(tmp_path / "scan")
    cs = open_artifact(str(tmp_path / "store" / "capture"))
    assert rep["capture"].status == "computed" and m.complete and cs.complete
    assert len(m.poses) == cs.read("images").shape[0] >= 5
    brackets = {len(p.exposures) for p in m.poses}
    assert brackets <= {1, 2, 3} and max(brackets) >= 2  # the exposure planner bracketed the highlight poses


@pytest.mark.slow  # a planned, bracketed virtual scan, then Debevec recovery of the response
def test_debevec_recovery_reads_a_planned_scan_whose_brackets_differ_per_pose(tmp_path, registry):
    """Issue 23: graphs/gonio-virtual.yaml's exposure planner gives poses different brackets; read without a
    recorded camera.response and response_method: debevec, that folder used to fail ("needs the same exposure
    times in every bracket").  The graph as shipped, with a smaller image and the response left out of the
    manifest."""
    import yaml

    from sbrdf_capture.response import relative_error

    g = yaml.safe_load((REPO / "graphs" / "gonio-virtual.yaml").read_text())
    folder = tmp_path / "scan"
    g["store"] = str(tmp_path / "store")
    g["nodes"] = {"capture": g["nodes"]["capture"]}
    p = g["nodes"]["capture"]["params"]
    p["path"] = str(folder)
    p["camera"]["params"].update(width=96, height=72, focal_px=360.0, texels=[16, 16], record_response=False)
    p["read"] = {"response_method": "debevec"}
    (tmp_path / "g.yaml").write_text(yaml.safe_dump(g))
    run_graph(str(tmp_path / "g.yaml"))
    manifest = json.loads((folder / MANIFEST).read_text())
    assert "response" not in manifest["camera"]
    brackets = {tuple(e["time_s"] for e in pose["exposures"]) for pose in manifest["poses"]}
    assert len([b for b in brackets if len(b) >= 2]) >= 2  # brackets of different times
    reader = registry.create("capture", "folder", {"path": str(folder), "response_method": "debevec"})
    assert reader.describe().camera["response"] == "table"
    truth = registry.create("device", "virtual-camera", p["camera"]["params"]).curve().table[:, 0]
    assert relative_error(reader.curve.table, truth, 0.1, 0.9, fit_scale=True) < 0.1


@pytest.mark.parametrize("change,message", [
    (lambda p: p["motors"]["light_arm"].pop("device"), "parameter motors.light_arm.device is required"),
    (lambda p: p["motors"]["light_arm"].update(speed=3), "unknown key motors.light_arm.speed"),
    (lambda p: p.update(camera={"params": {}}), "parameter camera.device is required"),
    (lambda p: p.update(geometry={"pan_limit_deg": [0, 1]}), "unknown key geometry.pan_limit_deg"),
    (lambda p: p.update(geometry={"tilt_limits_deg": [0, 1, 2]}), "'geometry.tilt_limits_deg' needs 2 items"),
    (lambda p: p.update(plan={"theta_d_deg": 20.0, "source": "stars"}), "'plan.source' is 'stars'"),
])
def test_nested_parameters_are_checked_against_their_declared_schema(registry, tmp_path, change, message):
    """motors, camera, geometry and plan declare their keys: a mistake is named by its path before anything runs."""
    from sbrdf_core.errors import PluginError

    params = {"path": str(tmp_path / "scan"), "motors": motors(), "plan": {"angles_deg": ANGLES}}
    change(params)
    with pytest.raises(PluginError, match=re.escape(message)):
        registry.create("capture", "gonio", params)


def test_a_folder_of_someone_elses_files_is_left_alone(tmp_path, start_simulator):
    """A capture folder without capture.json that holds files is not the writer's: the capture fails naming
    it, and every file there stays as it was."""
    from sbrdf_core.errors import SbrdfError

    sims = rig_sims(start_simulator)
    graph, store, folder = write_graph(tmp_path, "foreign", n_poses=2, motors=ports(sims))
    (folder / "images").mkdir(parents=True)
    (folder / "notes.txt").write_text("the user's notes\n")
    (folder / "images" / "p00000_e0.png").write_bytes(b"someone else's image")
    before = folder_files(folder)
    with pytest.raises(SbrdfError, match="left alone") as e:
        run_graph(str(graph))
    assert str(folder) in str(e.value)
    assert folder_files(folder) == before
