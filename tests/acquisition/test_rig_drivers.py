"""The serial drivers against their protocol simulators, through a real pty and pyserial.

Every fault the simulators can inject is exercised on both controllers, once
transient (the driver must recover and land where it was told) and once
persistent (the driver must stop the motors, close the port and raise an
error naming the port, the command and what came back).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest

from sbrdf_core.errors import SbrdfError
from sbrdf_devices.motors.indexer import Indexer
from sbrdf_devices.motors.ptu import PanTiltUnit
from sbrdf_devices.motors.sim import Fault, SimulatedIndexer, SimulatedPTU
from sbrdf_lib.serial.errors import (
    DeviceClosed,
    DeviceError,
    DeviceRefused,
    GarbledReply,
    ImplausibleReply,
    LinkLost,
    PositionError,
    ReplyTimeout,
    SoftLimitError,
)

TIMEOUT_S = 0.15
STALL_S = 0.25  # longer than the timeout: the reply arrives after the driver has given up on it


@dataclass(frozen=True)
class Rig:
    """How to drive one controller kind in these tests."""

    name: str
    simulator: type
    driver: type
    move: dict            # a reachable target
    out_of_range: dict    # a target outside the soft limits
    move_command: str     # regex of the command whose reply acknowledges a move
    query_command: str    # regex of the position query
    miss_command: str     # regex of the command a "miss" fault attaches to
    halt_command: str

    def true_position(self, sim) -> float:
        return sim.position_deg("pan") if self.simulator is SimulatedPTU else sim.position_deg(1)

    def connect(self, sim, **kwargs):
        return self.driver(port=sim.port, timeout_s=TIMEOUT_S, **{"retries": 2, **kwargs})


PTU = Rig("ptu", SimulatedPTU, PanTiltUnit, {"pan_deg": 20.0}, {"pan_deg": 170.0},
          r"PP-?\d+", "PP", r"PP-?\d+", "H")
INDEXER = Rig("indexer", SimulatedIndexer, Indexer, {"angle_deg": 45.0}, {"angle_deg": 5.0},
              "GO1", r"!1TPE", "GO.*", "!S")
RIGS = [PTU, INDEXER]


def value(position: dict) -> float:
    return next(iter(position.values()))


# -- normal operation ---------------------------------------------------------------------------------------------


def test_ptu_connects_moves_and_reads_back(start_simulator):
    sim = start_simulator(SimulatedPTU)
    with PanTiltUnit(port=sim.port, timeout_s=TIMEOUT_S) as ptu:
        assert ptu.arcsec_per_step == {"pan_deg": 46.2857, "tilt_deg": 46.2857}
        assert ptu.limits["pan_deg"] == pytest.approx((-159.0, 159.0), abs=0.02)
        assert ptu.limits["tilt_deg"] == pytest.approx((-47.0, 31.0), abs=0.02)
        got = ptu.move_to(pan_deg=30.0, tilt_deg=-10.0)
        assert got == pytest.approx({"pan_deg": 30.0, "tilt_deg": -10.0}, abs=0.0065)  # half a step
        assert ptu.position() == got
        assert ptu.move_to(**got) == got  # position() round-trips through move_to
        ptu.move_to(tilt_deg=5.0)
        assert ptu.position()["pan_deg"] == pytest.approx(30.0, abs=0.0065)
    assert sim.position_deg("tilt") == pytest.approx(5.0, abs=0.0065)
    assert sim.received[:3] == ["ED", "FV", "I"]  # echo off first: the factory default echoes
    assert "PP2333" in sim.received and "A" in sim.received
    assert sim.received[-1] == "H"  # the context manager halts before closing
    assert not ptu.is_open


def test_indexer_connects_moves_and_programs_its_own_limits(start_simulator):
    sim = start_simulator(SimulatedIndexer)
    with Indexer(port=sim.port, timeout_s=TIMEOUT_S) as arm:
        assert arm.steps_per_deg == 6250.0  # 25000 steps/rev x 90:1 -> 1.6e-4 deg, Table 3.1
        assert arm.position() == {"angle_deg": 90.0}
        assert arm.move_to(angle_deg=45.5) == {"angle_deg": 45.5}
        assert sim.position_deg() == pytest.approx(45.5)
    assert {"ECHO0", "ERRLVL4", "COMEXC0", "1MA1", "1LS3"} <= set(sim.received)
    assert sim.settings["LSPOS"][0] > 175 * 6250 and sim.settings["LSNEG"][0] < 10 * 6250
    assert "1D+284375" in sim.received and "GO1" in sim.received
    assert sim.received[-1] == "!S"


def test_devices_are_registered_plugins(start_simulator, registry):
    assert {"ptu", "indexer"} <= set(registry.names("device"))
    sim = start_simulator(SimulatedPTU)
    ptu = registry.create("device", "ptu", {"port": sim.port, "timeout_s": TIMEOUT_S, "tilt_limits_deg": [-20, 20]})
    with ptu:
        assert isinstance(ptu, PanTiltUnit)
        assert ptu.limits["tilt_deg"] == (-20.0, 20.0)
    with pytest.raises(SbrdfError, match="unknown parameter 'speed'.*accepted"):
        registry.create("device", "indexer", {"port": sim.port, "speed": 3})


@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
def test_reconnecting_finds_the_motor_where_it_was_left(start_simulator, rig):
    """What a resumed capture relies on: a new driver on the same port reads the current position."""
    sim = start_simulator(rig.simulator)
    with rig.connect(sim) as first:
        moved = first.move_to(**rig.move)
    with rig.connect(sim) as second:
        assert second.position().items() >= moved.items()


# -- soft limits ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
@pytest.mark.parametrize("bad", ["range", "nan", "unknown-axis"])
def test_soft_limits_refuse_before_anything_is_sent(start_simulator, rig, bad):
    sim = start_simulator(rig.simulator)
    with rig.connect(sim) as driver:
        sent = list(sim.received)
        target = {"range": rig.out_of_range, "nan": {k: math.nan for k in rig.move}, "unknown-axis": {"roll_deg": 1.0}}[bad]
        with pytest.raises(SoftLimitError) as info:
            driver.move_to(**target)
        assert sim.received == sent, "a refused move must send nothing"
        assert sim.port in str(info.value)
        assert (next(iter(target)) in str(info.value)) or bad == "unknown-axis"
        assert driver.is_open  # a refused target is the caller's mistake, not a device failure
        driver.move_to(**rig.move)


def test_ptu_user_limits_narrow_the_units_own(start_simulator):
    sim = start_simulator(SimulatedPTU, tilt_limits_deg=(-30.0, 30.0))
    with PanTiltUnit(port=sim.port, timeout_s=TIMEOUT_S, tilt_limits_deg=(-80.0, 10.0)) as ptu:
        assert ptu.limits["tilt_deg"] == pytest.approx((-30.0, 10.0), abs=0.02)
        with pytest.raises(SoftLimitError, match=r"tilt_deg=20 deg is outside the soft limits \[-29.99"):
            ptu.move_to(tilt_deg=20.0)


@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
def test_a_controller_refusal_is_not_retried_and_stops_cleanly(start_simulator, rig):
    """If the driver's limits are wrong, the controller's own limit refuses the move: stop, do not retry."""
    sim = start_simulator(rig.simulator)
    driver = rig.connect(sim)
    axis = next(iter(rig.move))
    driver.limits[axis] = (-400.0, 400.0)  # pretend the soft limits were misconfigured
    target = {axis: 300.0}
    with pytest.raises(DeviceRefused) as info:
        driver.move_to(**target)
    message = str(info.value)
    assert sim.port in message and "refused" in message
    if rig is PTU:
        assert "Maximum allowable Pan position" in message
        assert sum(c.startswith("PP") and c != "PP" for c in sim.received) == 1
    else:
        assert "SOFTWARE LIMIT" in message
        assert sim.received.count("GO1") == 1
    assert sim.received[-1] == rig.halt_command
    assert not driver.is_open


# -- faults: transient ones are retried ------------------------------------------------------------------------------


TRANSIENT = [("drop", "move"), ("drop", "query"), ("garble", "move"), ("garble", "query"),
             ("stall", "move"), ("stall", "query")]


@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
@pytest.mark.parametrize("kind,where", TRANSIENT, ids=[f"{k}-{w}" for k, w in TRANSIENT])
def test_transient_reply_faults_are_retried(start_simulator, rig, kind, where):
    sim = start_simulator(rig.simulator)
    with rig.connect(sim) as driver:
        match = rig.move_command if where == "move" else rig.query_command
        fault = sim.add_fault(Fault(kind, match=match, times=1, stall_s=STALL_S))
        got = driver.move_to(**rig.move)
        assert fault.fired == 1
        assert driver.link.recovered, "the exchange should have needed a second attempt"
        assert value(got) == pytest.approx(value(rig.move), abs=driver.tolerance_deg)
        assert rig.true_position(sim) == pytest.approx(value(rig.move), abs=driver.tolerance_deg)
        # the link is clean afterwards: late replies did not shift later answers
        assert driver.position() == got
        assert driver.move_to(**got) == got


@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
def test_a_transient_position_miss_is_recommanded(start_simulator, rig):
    sim = start_simulator(rig.simulator)
    with rig.connect(sim) as driver:
        sim.add_fault(Fault("miss", match=rig.miss_command, times=1, miss_deg=0.8))
        got = driver.move_to(**rig.move)
        assert value(got) == pytest.approx(value(rig.move), abs=driver.tolerance_deg)
        (axis, target, read), = driver.position_misses
        assert read - target == pytest.approx(0.8, abs=0.01)


# -- faults: persistent ones stop the rig with a clear error ---------------------------------------------------------------

PERSISTENT = [("drop", ReplyTimeout, "no complete reply"), ("garble", GarbledReply, "reply is not ASCII"),
              ("stall", ReplyTimeout, "no complete reply")]


@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
@pytest.mark.parametrize("kind,error,says", PERSISTENT, ids=[p[0] for p in PERSISTENT])
def test_persistent_reply_faults_stop_with_a_clear_error(start_simulator, rig, kind, error, says):
    sim = start_simulator(rig.simulator)
    driver = rig.connect(sim)
    sim.add_fault(Fault(kind, match=rig.query_command, times=None, stall_s=STALL_S))
    with pytest.raises(error) as info:
        driver.move_to(**rig.move)
    message = str(info.value)
    command = rig.query_command.replace("\\", "")
    assert sim.port in message and says in message and "gave up after 3 attempts" in message
    assert f"command {command!r}" in message
    assert isinstance(info.value, DeviceError) and isinstance(info.value, SbrdfError)
    assert info.value.command == command
    assert rig.halt_command in sim.received[-3:], "the driver must halt the motors on a fatal error"
    assert not driver.is_open
    with pytest.raises(DeviceClosed, match="closed"):
        driver.position()
    driver.close()  # closing twice is harmless


@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
def test_a_persistent_position_miss_raises_position_error(start_simulator, rig):
    sim = start_simulator(rig.simulator)
    driver = rig.connect(sim)
    sim.add_fault(Fault("miss", match=rig.miss_command, times=None, miss_deg=-1.5))
    with pytest.raises(PositionError) as info:
        driver.move_to(**rig.move)
    message = str(info.value)
    axis = next(iter(rig.move))
    assert f"{axis} read back" in message and "tolerance 0.05 deg" in message and "on 3 attempts" in message
    assert sim.port in message and "received '*" in message
    assert len(driver.position_misses) == 3
    assert sim.received[-1] == rig.halt_command
    assert not driver.is_open


def test_a_stalled_await_times_out_from_the_move_not_the_rig(start_simulator):
    """The await timeout scales with the expected travel, so a stalled ``A`` is caught quickly."""
    sim = start_simulator(SimulatedPTU)
    ptu = PanTiltUnit(port=sim.port, timeout_s=TIMEOUT_S, retries=0, move_timeout_s=120.0, speed_deg_s=200.0)
    sim.add_fault(Fault("stall", match="A", times=None, stall_s=5.0))
    with pytest.raises(ReplyTimeout, match=r"command 'A'"):
        ptu.move_to(pan_deg=1.0)
    assert not ptu.is_open


def test_echoed_commands_are_skipped_and_stop_works_mid_session(start_simulator):
    sim = start_simulator(SimulatedIndexer, echo=True)
    with Indexer(port=sim.port, timeout_s=TIMEOUT_S) as arm:
        arm.stop()
        assert sim.received[-1] == "!S"
        assert arm.move_to(angle_deg=170.0) == {"angle_deg": 170.0}


def test_opening_a_missing_port_names_it():
    with pytest.raises(DeviceError, match=r"ptu on /dev/does-not-exist: cannot open serial port"):
        PanTiltUnit(port="/dev/does-not-exist")


# -- values that can be verified are (issue 21): line noise that stays valid ASCII -------------------------------------


def test_a_corrupted_but_ascii_resolution_reply_is_requeried_not_believed(start_simulator):
    """``46.2857`` read once as ``41.2857`` (one digit changed, still a valid reply) must not skew every pan pose."""
    sim = start_simulator(SimulatedPTU, faults=[Fault("corrupt", match="PR", times=1)])
    with PanTiltUnit(port=sim.port, timeout_s=TIMEOUT_S, retries=2) as ptu:
        assert sim.faults[0].fired == 1
        assert ptu.arcsec_per_step == {"pan_deg": 46.2857, "tilt_deg": 46.2857}
        assert ptu.reread == [("pan resolution", [41.2857, 46.2857, 46.2857])]
        ptu.move_to(pan_deg=100.0)
    assert sim.position_deg("pan") == pytest.approx(100.0, abs=0.0065)


@pytest.mark.parametrize("query", ["PR", "PN"])
def test_a_persistently_corrupted_constant_stops_before_any_motion(start_simulator, query):
    """Every reading the same wrong value: the model check (resolution, limit range) refuses it, naming the readings."""
    sim = start_simulator(SimulatedPTU, faults=[Fault("corrupt", match=query, times=None, digit=0)])
    with pytest.raises(ImplausibleReply) as info:
        PanTiltUnit(port=sim.port, timeout_s=TIMEOUT_S, retries=2)
    message = str(info.value)
    assert sim.port in message and f"command {query!r}" in message and "readings" in message
    assert info.value.readings and len(set(info.value.readings)) == 1
    if query == "PR":
        assert "96.2857" in message and "none of the controller model's resolutions" in message
    else:  # -12367 positions read as -62367: beyond a full turn
        assert "-62367 positions is -801.9 deg, beyond a full turn" in message
    assert not any(c.startswith(("PP", "TP")) and c[2:] for c in sim.received), "nothing may move"
    assert sim.received[-1] == "H"


def test_resolutions_of_another_model_are_accepted_when_declared(start_simulator):
    sim = start_simulator(SimulatedPTU, resolution_arcsec=12.96)
    with pytest.raises(ImplausibleReply, match="12.96 arc-seconds per position is none of"):
        PanTiltUnit(port=sim.port, timeout_s=TIMEOUT_S)
    with PanTiltUnit(port=sim.port, timeout_s=TIMEOUT_S, resolutions_arcsec=[12.96]) as ptu:
        assert ptu.arcsec_per_step["pan_deg"] == 12.96
    with PanTiltUnit(port=sim.port, timeout_s=TIMEOUT_S, resolutions_arcsec=[]) as ptu:  # agreement only
        assert ptu.arcsec_per_step["tilt_deg"] == 12.96


@pytest.mark.parametrize("rig,query", [(PTU, "PS"), (INDEXER, "1LSPOS")], ids=["ptu-speed", "indexer-soft-limit"])
def test_a_setting_is_read_back_and_a_mismatch_refused(start_simulator, rig, query):
    """A setting whose read-back (agreeing with itself) differs from what was sent is re-sent once, then refused."""
    sim = start_simulator(rig.simulator, faults=[Fault("corrupt", match=query, times=None, digit=2)])
    with pytest.raises(ImplausibleReply, match="reads back .* after setting") as info:
        rig.connect(sim)
    assert sim.port in str(info.value) and f"command {query!r}" in str(info.value)
    assert sum(c.startswith(query) and c != query for c in sim.received) == 2, "the setting is re-sent once"
    assert sim.received[-1] == rig.halt_command


def test_indexer_resolution_is_requeried_after_a_corrupted_reading(start_simulator):
    sim = start_simulator(SimulatedIndexer, faults=[Fault("corrupt", match="1DRES", times=1, digit=1)])
    with Indexer(port=sim.port, timeout_s=TIMEOUT_S) as arm:
        assert arm.steps_per_deg == 6250.0
        assert arm.reread == [("drive resolution", [75000, 25000, 25000])]
        assert arm.move_to(angle_deg=45.5) == {"angle_deg": 45.5}
    assert sim.position_deg() == pytest.approx(45.5)


# -- the device disappears (issue 21): an OS-level failure is a driver error -----------------------------------------------


@pytest.mark.parametrize("rig", RIGS, ids=lambda r: r.name)
@pytest.mark.parametrize("when", ["mid-move", "between-moves"])
def test_a_vanishing_device_is_a_driver_error_naming_port_command_and_target(start_simulator, rig, when):
    sim = start_simulator(rig.simulator)
    driver = rig.connect(sim)
    if when == "mid-move":  # the adapter is pulled out as the move command arrives: the reply read fails
        sim.add_fault(Fault("vanish", match=rig.move_command, times=1))
    else:  # it was pulled out while idle: the next write (tcflush) fails with termios.error EIO
        sim.unplug()
    with pytest.raises(LinkLost) as info:
        driver.move_to(**rig.move)
    e = info.value
    message = str(e)
    axis, target = next(iter(rig.move.items()))
    assert isinstance(e, DeviceError) and isinstance(e, SbrdfError)
    assert message.startswith(f"{rig.name} on {sim.port}: serial link lost")
    assert e.port == sim.port and e.command and f"command {e.command!r}" in message
    assert f"while moving to {axis}={target:.4f}" in message
    assert "halt could not be sent" in message and "port closed" in message
    if when == "between-moves":
        assert "termios.error: [Errno 5] Input/output error" in message
    assert not driver.is_open
    with pytest.raises(DeviceClosed):
        driver.position()
    driver.close()


def test_a_device_back_under_the_same_name_is_still_halted(start_simulator, tmp_path):
    """A USB glitch: the port vanishes and the controller reappears under the same path; the halt reaches it."""
    first, back = start_simulator(SimulatedPTU), start_simulator(SimulatedPTU)
    port = tmp_path / "ttyPTU"
    port.symlink_to(first.port)
    ptu = PanTiltUnit(port=str(port), timeout_s=TIMEOUT_S, retries=2)
    first.unplug()
    port.unlink()
    port.symlink_to(back.port)  # what udev does when the adapter re-enumerates
    with pytest.raises(LinkLost, match=r"while moving to pan_deg=20.0000; halt acknowledged after reopening the port; "
                                       r"port closed \(command 'PP1556'"):
        ptu.move_to(pan_deg=20.0)
    assert back.received == ["H"] and not ptu.is_open
