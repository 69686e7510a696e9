"""A simulated Compumotor 6000-style indexer (see :mod:`sbrdf_devices.motors.indexer` for the protocol).

Defaults: one axis, 25000 steps/rev drive and encoder resolution, a 90:1
gearbox assumed by :attr:`steps_per_deg` (so fault offsets can be given in
degrees), echo on and ``ERRLVL4`` prompts, ``COMEXC0``: a buffered command
sent while an axis moves waits until the motion ends; ``!`` commands do not.

Axis status (``TAS``) is 32 bits in groups of four separated by ``_``; bit 1
is "moving", bit 15 "positive soft limit hit", bit 16 "negative soft limit
hit" (set when a ``GO`` is refused because its target is beyond an enabled
soft limit; the move is then not started and the error prompt ``?`` sent).
"""

from __future__ import annotations

import re

from sbrdf_lib.serial.sim import PtySimulator, SimulatedAxis

_COMMAND = re.compile(r"^(?P<axis>[1-4])?(?P<name>[A-Z]+)(?P<arg>.*)$")
_NUMERIC = ("D", "V", "A", "AD", "LSPOS", "LSNEG", "LS", "LH")


class SimulatedIndexer(PtySimulator):
    """6000-series indexer on a pty; ``with SimulatedIndexer() as sim: Indexer(port=sim.port)``."""

    def __init__(self, faults=(), axes: int = 1, drive_resolution: int = 25000, encoder_resolution: int = 25000,
                 gear_ratio: float = 90.0, echo: bool = True, time_scale: float = 0.002, max_move_s: float = 0.05,
                 angle_deg: float = 90.0):
        super().__init__(faults, echo=echo, time_scale=time_scale, max_move_s=max_move_s)
        self.n_axes = int(axes)
        self.gear_ratio = float(gear_ratio)
        self.errlvl = 4
        self.comexc = 0
        n = self.n_axes
        #: Per-axis settings by command name: counts and flags are ints, velocities and accelerations floats.
        self.settings: dict[str, list[float]] = {"DRES": [int(drive_resolution)] * n, "ERES": [int(encoder_resolution)] * n,
                         "MA": [0] * n, "V": [1.0] * n, "A": [10.0] * n, "AD": [10.0] * n,
                         "D": [0] * n, "LSPOS": [0] * n, "LSNEG": [0] * n, "LS": [0] * n, "LH": [0] * n}
        start = round(angle_deg * self.steps_per_deg)
        self.motors = [SimulatedAxis(start, drive_resolution, time_scale, max_move_s) for _ in range(n)]
        self.limit_hit = [(False, False)] * n

    @property
    def steps_per_deg(self) -> float:
        return self.settings["DRES"][0] * self.gear_ratio / 360.0

    def position_deg(self, axis: int = 1) -> float:
        """True output-shaft angle of ``axis`` in degrees (what the motor did, faults included)."""
        return self.motors[axis - 1].position() / self.steps_per_deg

    # -- replies ------------------------------------------------------------------------

    def _ok(self, *data: str) -> str | None:
        return self.eol.join([*data, ">"]) if self.errlvl >= 4 else self.eol.join(data) or None

    def _error(self, message: str) -> str:
        return self.eol.join([f"*{message}", "?"]) if self.errlvl >= 4 else f"*{message}"

    def _encoder(self, i: int) -> int:
        counts = self.motors[i].position() * self.settings["ERES"][i] / self.settings["DRES"][i]
        return round(counts)

    def _status(self, i: int) -> str:
        bits = ["0"] * 32
        bits[0] = "1" if self.motors[i].moving() else "0"
        bits[14] = "1" if self.limit_hit[i][0] else "0"
        bits[15] = "1" if self.limit_hit[i][1] else "0"
        return "_".join("".join(bits[k:k + 4]) for k in range(0, 32, 4))

    # -- commands -----------------------------------------------------------------------

    def handle(self, command: str) -> str | None:
        cmd = command.upper()
        immediate = cmd.startswith("!")
        body = cmd[1:] if immediate else cmd
        if not immediate and self.comexc == 0:
            while any(m.moving() for m in self.motors):  # COMEXC0: the buffer waits for motion to end
                if not self.wait(0.002):
                    return None
        m = _COMMAND.match(body)
        if not m:
            return self._error("INVALID COMMAND")
        axis = int(m["axis"]) if m["axis"] else None
        name, arg = m["name"], m["arg"]
        if axis is not None and axis > self.n_axes:
            return self._error(f"INVALID AXIS {axis}")
        targets = [axis - 1] if axis else list(range(self.n_axes))
        try:
            return self._execute(name, arg, axis, targets, body)
        except ValueError:
            return self._error(f"INVALID DATA-FIELD {arg}")

    def _execute(self, name: str, arg: str, axis: int | None, targets: list[int], body: str) -> str | None:
        prefix = f"{axis}" if axis else ""
        if name == "ECHO":
            self.echo = arg == "1"
            return self._ok()
        if name == "ERRLVL":
            self.errlvl = int(arg)
            return self._ok()
        if name == "COMEXC":
            self.comexc = int(arg)
            return self._ok()
        if name == "TREV":
            return self._ok("*TREV92-016740-01-4.2 6000 SIMULATOR")
        if name in ("S", "K"):
            for i in targets:
                self.motors[i].halt()
            return self._ok()
        if name in ("TPE", "TPM"):
            values = [self._encoder(i) if name == "TPE" else round(self.motors[i].position()) for i in targets]
            return self._ok(f"*{prefix}{name}" + ",".join(f"{v:+d}" for v in values))
        if name == "TAS":
            return self._ok(f"*{prefix}TAS" + ",".join(self._status(i) for i in targets))
        if name in ("DRES", "ERES"):
            if arg:
                for i, v in self._values(arg, targets, int):
                    self.settings[name][i] = v
                return self._ok()
            return self._ok(f"*{prefix}{name}" + ",".join(str(self.settings[name][i]) for i in targets))
        if name == "MA":
            if not arg:
                return self._ok(f"*{prefix}MA" + "".join(str(self.settings["MA"][i]) for i in targets))
            digits = arg if axis is None else arg[:1]
            for i, d in zip(targets, digits):
                if d not in "01X":
                    raise ValueError(arg)
                if d != "X":
                    self.settings["MA"][i] = int(d)
            return self._ok()
        if name in _NUMERIC:
            convert = int if name in ("D", "LSPOS", "LSNEG", "LS", "LH") else float
            if not arg:
                fmt = (lambda v: f"{v:+d}") if name in ("D", "LSPOS", "LSNEG") else str
                return self._ok(f"*{prefix}{name}" + ",".join(fmt(self.settings[name][i]) for i in targets))
            for i, v in self._values(arg, targets, convert):
                self.settings[name][i] = v
            return self._ok()
        if name == "GO":
            return self._go(arg, axis)
        return self._error("INVALID COMMAND")

    @staticmethod
    def _values(arg: str, targets: list[int], convert):
        fields = arg.split(",")
        if len(fields) > len(targets):
            raise ValueError(arg)
        return [(i, convert(f)) for i, f in zip(targets, fields) if f != ""]

    def _go(self, arg: str, axis: int | None) -> str | None:
        mask = arg or "1" * self.n_axes
        if axis is not None:
            mask = "".join("1" if i == axis - 1 else "0" for i in range(self.n_axes))
        if len(mask) > self.n_axes or any(c not in "01X" for c in mask):
            raise ValueError(arg)
        moves = []
        for i, c in enumerate(mask):
            if c != "1":
                continue
            motor = self.motors[i]
            distance = self.settings["D"][i]
            target = distance if self.settings["MA"][i] else round(motor.target) + distance
            ls = int(self.settings["LS"][i])  # a bit mask (LS takes ints)
            if ls & 1 and target > self.settings["LSPOS"][i] or ls & 2 and target < self.settings["LSNEG"][i]:
                positive = target > self.settings["LSPOS"][i]
                self.limit_hit[i] = (positive, not positive)
                side = "POSITIVE" if positive else "NEGATIVE"
                return self._error(f"{side} SOFTWARE LIMIT ON AXIS {i + 1}: MOVE NOT MADE")
            moves.append((i, target))
        for i, target in moves:
            self.limit_hit[i] = (False, False)
            motor = self.motors[i]
            motor.speed = max(self.settings["V"][i] * self.settings["DRES"][i], 1.0)
            fault = self.take_fault(("miss",), f"GO{arg}" if axis is None else f"{axis}GO{arg}")
            motor.move(target + (round(fault.miss_deg * self.steps_per_deg) if fault else 0))
        return self._ok()
