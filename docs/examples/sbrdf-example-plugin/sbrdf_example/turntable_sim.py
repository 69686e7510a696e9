"""A simulated turntable on a pseudo-terminal (protocol: :mod:`sbrdf_example.turntable`).

Built on :class:`sbrdf_lib.serial.PtySimulator`, which owns the pty, the
serving thread and the reply faults (``drop``, ``garble``, ``stall``); this
class only answers commands, and applies ``miss`` faults to ``G`` moves.
The driver under test opens ``sim.port`` with pyserial exactly as it would
open ``/dev/ttyUSB0``::

    with SimulatedTurntable(faults=[Fault("drop", match="Q", times=1)]) as sim:
        with Turntable(port=sim.port, timeout_s=0.2) as stage:
            stage.move_to(angle_deg=30.0)
"""

from __future__ import annotations

import re

from sbrdf_lib.serial import PtySimulator, SimulatedAxis

__all__ = ["SimulatedTurntable"]

_GO = re.compile(r"^G(?P<angle>[+-]?\d+(?:\.\d*)?)$")


class SimulatedTurntable(PtySimulator):
    """The stage: millidegree steps, a hardware range of ±``range_deg``, no echo."""

    def __init__(self, faults=(), range_deg: float = 720.0, speed_deg_s: float = 30.0, time_scale: float = 0.002,
                 max_move_s: float = 0.05, angle_deg: float = 0.0):
        super().__init__(faults, echo=False, time_scale=time_scale, max_move_s=max_move_s)
        self.range_deg = float(range_deg)
        self.motor = SimulatedAxis(round(angle_deg * 1000), speed_deg_s * 1000, time_scale, max_move_s)

    def position_deg(self) -> float:
        """True angle in degrees (what the motor did, faults included)."""
        return self.motor.position() / 1000.0

    def handle(self, command: str) -> str | None:
        cmd = command.upper()
        if cmd == "Q":
            state = "MOVING" if self.motor.moving() else "IDLE"
            return f"Q {round(self.motor.position()) / 1000:+08.3f} {state}"
        if cmd == "S":
            self.motor.halt()
            return "OK"
        m = _GO.match(cmd)
        if not m:
            return "ERR UNKNOWN COMMAND"
        target = float(m["angle"])
        if abs(target) > self.range_deg:
            return f"ERR RANGE {target:+.3f} OUTSIDE +-{self.range_deg:g}"
        fault = self.take_fault(("miss",), cmd)
        self.motor.move(round((target + (fault.miss_deg if fault else 0.0)) * 1000))
        return "OK"
