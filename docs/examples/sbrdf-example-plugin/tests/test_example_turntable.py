"""The turntable driver against its pty simulator: what a third-party device plugin tests in its own repository.

Nothing is mocked: :class:`~sbrdf_example.turntable_sim.SimulatedTurntable`
serves the protocol on a pseudo-terminal and the driver opens it with
pyserial, as it would open ``/dev/ttyUSB0``.  Faults are data
(:class:`sbrdf_lib.serial.Fault`).  Only ``sbrdf_core`` and ``sbrdf_lib``
(sbrdf's public layers) are imported, so these tests keep passing whatever
happens to sbrdf's built-in plugins.  Run with
``pytest docs/examples/sbrdf-example-plugin/tests``.
"""

from __future__ import annotations

import pytest

from sbrdf_core.params import REQUIRED

pytest.importorskip("serial", reason="sbrdf_lib.serial and the turntable need pyserial (sbrdf[rig])")

from sbrdf_example.turntable import Turntable  # noqa: E402  (after the skip: these import pyserial)
from sbrdf_example.turntable_sim import SimulatedTurntable  # noqa: E402
from sbrdf_lib.serial import DeviceClosed, DeviceRefused, Fault, GarbledReply, LinkLost, ReplyTimeout, SoftLimitError  # noqa: E402


@pytest.fixture
def simulator():
    """``sim = simulator(faults=[...], ...)``: started now, stopped (and checked for thread errors) at teardown."""
    started = []

    def start(**kwargs):
        sim = SimulatedTurntable(**kwargs).start()
        started.append(sim)
        return sim

    yield start
    for sim in started:
        sim.stop()
        assert sim.error is None, f"simulator thread failed: {sim.error!r}"


def test_01_declared_parameters_match_the_constructor():
    """``Turntable.params`` is what the registry validates graphs with; ``__init__`` must take the same keywords."""
    import inspect

    sig = inspect.signature(Turntable.__init__).parameters
    for p in Turntable.params:
        arg = sig[p.name]
        assert arg.kind is arg.KEYWORD_ONLY, p.name
        if p.default is REQUIRED:
            assert arg.default is arg.empty, p.name
        else:
            default = list(arg.default) if isinstance(p.default, list) else arg.default
            assert default == p.default, p.name
    assert {p.name for p in Turntable.params} == set(sig) - {"self"}


def test_02_moves_verifies_and_stops(simulator):
    sim = simulator()
    with Turntable(port=sim.port) as stage:
        assert stage.move_to(angle_deg=-37.5) == {"angle_deg": -37.5}
        assert stage.position() == {"angle_deg": -37.5} and sim.position_deg() == -37.5
        stage.move_to(**stage.position())  # a no-op round trip
        stage.stop()
    assert not stage.is_open
    assert sim.received[:2] == ["Q", "G-37.500"] and sim.received[-1] == "S"  # connect probes; close halts


@pytest.mark.parametrize("target", [-180.0, -0.001, 0.0, 12.3456, 180.0])
def test_03_reaches_angles_inside_the_limits_to_the_stage_resolution(simulator, target):
    sim = simulator()
    with Turntable(port=sim.port) as stage:
        assert abs(stage.move_to(angle_deg=target)["angle_deg"] - target) <= 5e-4
        assert abs(sim.position_deg() - target) <= 5e-4


@pytest.mark.parametrize("target", [-180.5, 200.0, float("nan")])
def test_04_a_target_outside_the_soft_limits_is_refused_unsent(simulator, target):
    sim = simulator()
    with Turntable(port=sim.port) as stage:
        before = list(sim.received)
        with pytest.raises(SoftLimitError, match=r"outside the soft limits \[-180, 180\] deg; nothing was sent"):
            stage.move_to(angle_deg=target)
        assert sim.received == before


def test_05_transient_faults_are_retried_and_recorded(simulator):
    # The first move's reply is dropped (the stage moved; the driver re-sends the absolute move), the first Q
    # after connecting is garbled and a later one late (both re-sent), and the re-sent move misses by 0.5 deg
    # (the read-back catches it and the move is commanded once more).
    sim = simulator(faults=[Fault("drop", match="G.*"), Fault("garble", match="Q", skip=1),
                            Fault("stall", match="Q", skip=3, stall_s=0.3), Fault("miss", skip=1, miss_deg=0.5)])
    with Turntable(port=sim.port, timeout_s=0.1, retries=2) as stage:
        assert stage.move_to(angle_deg=90.0) == {"angle_deg": 90.0}
        assert sim.position_deg() == 90.0
        failures = " ".join(err for _, err in stage.link.recovered)
        assert "no complete reply" in failures and "not ASCII" in failures
        assert stage.position_misses == [("angle_deg", 90.0, 90.5)]


@pytest.mark.parametrize("kind,error,message", [("drop", ReplyTimeout, "no complete reply within 0.1 s"),
                                                ("garble", GarbledReply, "reply is not ASCII")])
def test_06_a_persistent_reply_fault_is_a_clear_error_and_closes_the_port(simulator, kind, error, message):
    sim = simulator()
    stage = Turntable(port=sim.port, timeout_s=0.1, retries=1)
    sim.add_fault(Fault(kind, match="Q", times=None))
    with pytest.raises(error) as info:
        stage.move_to(angle_deg=10.0)
    assert str(info.value).startswith(f"turntable on {sim.port}: {message}; gave up after 2 attempts "
                                      "(command 'Q', received ")
    assert info.value.command == "Q" and info.value.port == sim.port
    assert not stage.is_open and sim.received[-1] == "S"  # halted (best effort) and released
    with pytest.raises(DeviceClosed, match="driver is closed"):
        stage.position()


def test_07_a_refusal_is_not_retried(simulator):
    sim = simulator(range_deg=90.0)  # the hardware range is narrower than the driver's soft limits
    stage = Turntable(port=sim.port)
    with pytest.raises(DeviceRefused, match=r"stage refused: RANGE \+120.000 OUTSIDE \+-90 .*command 'G\+120.000'"):
        stage.move_to(angle_deg=120.0)
    assert sim.received.count("G+120.000") == 1 and not stage.is_open


def test_08_something_else_on_the_port_fails_at_connect(simulator):
    sim = simulator()
    sim.handle = lambda command: "HELLO"  # a different device answers
    with pytest.raises(GarbledReply, match=r"expected 'Q <angle> MOVING\|IDLE'.*received 'HELLO'"):
        Turntable(port=sim.port, timeout_s=0.2, retries=0)


def test_09_an_unplugged_stage_is_a_lost_link_naming_the_port(simulator):
    sim = simulator()
    stage = Turntable(port=sim.port, timeout_s=0.2, retries=1)
    sim.unplug()
    with pytest.raises(LinkLost, match=f"turntable on {sim.port}: serial link lost") as info:
        stage.move_to(angle_deg=10.0)
    assert "while moving to angle_deg=10.0000" in str(info.value) and not stage.is_open
