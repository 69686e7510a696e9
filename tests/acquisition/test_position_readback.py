"""A position reply corrupted by line noise (still valid ASCII, inside the move tolerance) is not recorded.

Every move is read back until two readings in a row agree: one corrupted
reading costs one more query, and the pose recorded is where the motor is.
"""

from __future__ import annotations

import pytest

from sbrdf_devices.motors.indexer import Indexer
from sbrdf_devices.motors.ptu import PanTiltUnit
from sbrdf_devices.motors.sim import Fault, SimulatedIndexer, SimulatedPTU
from sbrdf_lib.serial.errors import ImplausibleReply

TIMEOUT_S = 0.15
LAST = 99  # a corrupt fault's digit past the end changes the reply's last digit: the smallest error


def test_indexer_position_corrupted_in_its_last_digit_is_requeried(start_simulator):
    sim = start_simulator(SimulatedIndexer)
    with Indexer(port=sim.port, timeout_s=TIMEOUT_S, retries=2) as arm:
        # 5 encoder counts = 0.0008 deg: far inside the 0.05 deg tolerance, believed when read once
        sim.add_fault(Fault("corrupt", match=r"!1TPE", times=1, digit=LAST))
        got = arm.move_to(angle_deg=45.0)
        assert got == {"angle_deg": pytest.approx(sim.position_deg(1), abs=1e-9)}
        assert got == {"angle_deg": 45.0}
        ((what, readings),) = arm.reread
        assert what == "position" and len(readings) == 3 and readings[0] != readings[1] == readings[2]
        assert not arm.position_misses


def test_ptu_position_corrupted_inside_the_tolerance_is_requeried(start_simulator):
    sim = start_simulator(SimulatedPTU)
    with PanTiltUnit(port=sim.port, timeout_s=TIMEOUT_S, retries=2, tolerance_deg=0.1) as ptu:
        true = ptu.move_to(pan_deg=20.0)
        sim.add_fault(Fault("corrupt", match="PP", times=1, digit=LAST))  # 5 positions = 0.064 deg < 0.1
        assert ptu.position() == true
        assert ptu.reread[-1][0] == "position" and len(ptu.reread[-1][1]) == 3


def test_a_position_that_never_reads_the_same_twice_stops_the_rig(start_simulator):
    sim = start_simulator(SimulatedIndexer)
    with Indexer(port=sim.port, timeout_s=TIMEOUT_S, retries=1) as arm:
        # each reading corrupted in another digit (the first fault that fires takes the command): none agree
        for digit in (6, 5, 4, 3, 2):
            sim.add_fault(Fault("corrupt", match=r"!1TPE", times=1, digit=digit))
        with pytest.raises(ImplausibleReply, match="never agreed twice in a row"):
            arm.move_to(angle_deg=30.0)
    assert sim.received[-1] == "!S"  # halted
