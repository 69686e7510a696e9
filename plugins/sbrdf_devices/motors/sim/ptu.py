"""A simulated Directed Perception-style pan-tilt unit (see :mod:`sbrdf_devices.motors.ptu` for the protocol).

Defaults follow a PTU-46-70 in eighth-step mode: 46.2857 arc-seconds per
position, pan ±159°, tilt −47°..+31°, echo on (the factory default), verbose
feedback.  Commands are whitespace-delimited; each reply is one line.
"""

from __future__ import annotations

import re

from sbrdf_lib.serial.sim import PtySimulator, SimulatedAxis

_COMMAND = re.compile(r"^(?P<axis>[PT])(?P<code>[PSNXRO])(?P<arg>[-+]?\d+)?$")
_NAMES = {"P": "Pan", "T": "Tilt"}


class SimulatedPTU(PtySimulator):
    """Pan-tilt unit on a pty; ``with SimulatedPTU(faults=[...]) as sim: PanTiltUnit(port=sim.port)``."""

    def __init__(self, faults=(), resolution_arcsec: float = 46.2857, pan_limits_deg=(-159.0, 159.0),
                 tilt_limits_deg=(-47.0, 31.0), speed: float = 1000.0, echo: bool = True,
                 time_scale: float = 0.002, max_move_s: float = 0.05, pan_deg: float = 0.0, tilt_deg: float = 0.0):
        super().__init__(faults, echo=echo, time_scale=time_scale, max_move_s=max_move_s)
        self.resolution_arcsec = float(resolution_arcsec)
        self.verbose = True
        per_deg = 3600.0 / self.resolution_arcsec
        self.limits = {"P": tuple(round(v * per_deg) for v in pan_limits_deg),
                       "T": tuple(round(v * per_deg) for v in tilt_limits_deg)}
        self.axes = {"P": SimulatedAxis(round(pan_deg * per_deg), speed, time_scale, max_move_s),
                     "T": SimulatedAxis(round(tilt_deg * per_deg), speed, time_scale, max_move_s)}

    @property
    def steps_per_deg(self) -> float:
        return 3600.0 / self.resolution_arcsec

    def position_deg(self, axis: str) -> float:
        """True position of ``"pan"`` or ``"tilt"`` in degrees (what the motor did, faults included)."""
        return self.axes[axis[0].upper()].position() / self.steps_per_deg

    def split(self, buffer: str) -> tuple[list[str], str]:
        *tokens, rest = re.split(r"\s", buffer)
        return [t for t in tokens if t], rest

    def _value(self, value, phrase: str) -> str:
        return f"* {phrase} {value}" if self.verbose else f"* {value}"

    def handle(self, command: str) -> str | None:
        cmd = command.upper()
        if cmd == "A":
            while any(axis.moving() for axis in self.axes.values()):
                if not self.wait(0.002):
                    return None
            return "*"
        if cmd in ("H", "HP", "HT"):
            for letter in ("PT" if cmd == "H" else cmd[1]):
                self.axes[letter].halt()
            return "*"
        if cmd in ("ED", "EE"):
            self.echo = cmd == "EE"
            return "*"
        if cmd in ("FV", "FT"):
            self.verbose = cmd == "FV"
            return "*"
        if cmd in ("I", "S"):
            return "*"
        if cmd == "V":
            return "* Pan-Tilt Controller (sbrdf simulator of a PTU-46-70)"
        m = _COMMAND.match(cmd)
        if not m:
            return "! Illegal Command"
        letter, code, arg = m["axis"], m["code"], m["arg"]
        name, axis = _NAMES[letter], self.axes[letter]
        lo, hi = self.limits[letter]
        if code == "P" and arg is None:
            return self._value(round(axis.position()), f"Current {name} position is")
        if code == "P" or (code == "O" and arg is not None):
            target = int(arg) if code == "P" else round(axis.target) + int(arg)
            if target > hi:
                return f"! Maximum allowable {name} position is {hi}"
            if target < lo:
                return f"! Minimum allowable {name} position is {lo}"
            fault = self.take_fault(("miss",), cmd)
            axis.move(target + (round(fault.miss_deg * self.steps_per_deg) if fault else 0))
            return "*"
        if code == "O":
            return self._value(round(axis.target), f"Target {name} position is")
        if code == "S":
            if arg is None:
                return self._value(round(axis.speed), f"Target {name} speed is")
            if int(arg) <= 0:
                return f"! Illegal {name} speed {arg}"
            axis.speed = float(arg)
            return "*"
        if arg is not None:
            return "! Illegal Command argument"
        if code == "N":
            return self._value(lo, f"Minimum {name} position is")
        if code == "X":
            return self._value(hi, f"Maximum {name} position is")
        return f"* {self.resolution_arcsec:.4f} seconds arc per position"  # code == "R"
