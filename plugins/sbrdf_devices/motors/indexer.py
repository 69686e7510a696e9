"""Driver for a rotary indexer speaking the Compumotor 6000-series command language.

The light arm of McAllister's rig swings on a Compumotor 6000-series indexer
(seed 000, §3.3, Table 3.1: 1.6e-4° resolution, 0.14° repeatability).  The
6000 language is line-oriented ASCII with axis-prefixed commands; the subset
this driver uses (``n`` is the axis number, 1..4):

===================  ==================================================  ======================
command              meaning                                             reply (``ERRLVL4``)
===================  ==================================================  ======================
``ECHO0``            stop echoing characters (factory default echoes)    ``>``
``ERRLVL4``          full error reporting: prompt ``>`` / ``?``          ``>``
``COMEXC0``          buffered commands wait for motion to finish         ``>``
``nMA1``             absolute positioning mode                           ``>``
``nDRES``            report drive resolution, steps/rev                  ``*1DRES25000`` ``>``
``nERES``            report encoder resolution, counts/rev               ``*1ERES25000`` ``>``
``nLSPOS<s>``        positive soft limit, steps (``nLSNEG`` negative)    ``>``
``nLS3``             enable both soft limits                             ``>``
``nV<r>``/``nA<r>``  velocity (rev/s) / acceleration (rev/s²)            ``>``
``nD<s>``            distance (absolute target under ``MA1``), steps     ``>``
``GO1``/``GO01``     start the axes marked ``1``                         ``>``
``!nTAS``            immediate: axis status, 32 bits, bit 1 = moving    ``*1TAS1000_0000_...``
``!nTPE``            immediate: encoder position                         ``*1TPE+4000`` ``>``
``!S``               immediate: stop all axes (decelerate)               ``>``
===================  ==================================================  ======================

Every text the controller sends starts with ``*``; under ``ERRLVL4`` each
command is answered by the prompt ``>`` when it was accepted, or by a
``*<message>`` line and the error prompt ``?`` when it was not (the real unit
sends the prompts without a line end; the simulator and this driver end every
line with CR LF).  ``!`` makes a command *immediate*: it bypasses the command
buffer, which with ``COMEXC0`` is blocked while an axis moves, so positions
and status are polled with ``!`` during motion.

Transfer replies repeat the command name (``*1TPE+4000``), so a stale reply to
another command is recognised as garbled rather than misread.

What is verified (a digit changed by line noise keeps a reply valid ASCII):
the drive and encoder resolutions (``DRES``/``ERES``) are read until two
readings in a row agree and lie in the 6000 series' range (``DRES`` 200 to
1,024,000 steps/rev); the soft limits (``LSPOS``/``LSNEG``), velocity and
acceleration are read back after they are set and must equal what was sent
(re-sent once if not); every move is read back from the encoder.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Sequence

from sbrdf_lib.serial.controller import MotorController
from sbrdf_lib.serial.errors import DeviceRefused, GarbledReply, ImplausibleReply, ReplyTimeout
from sbrdf_lib.serial.link import SerialLink

from ..declarations import INDEXER

logger = logging.getLogger(__name__)

_PROMPTS = (">", "?")
#: Plausible resolutions, steps (counts) per motor revolution: the 6000 series accepts DRES 200..1,024,000.
DRES_RANGE = (200, 1_024_000)
ERES_RANGE = (1, 16_777_216)


class Indexer(MotorController):
    """One axis of a Compumotor 6000-style indexer, in degrees at the output shaft.

    ``gear_ratio`` is motor revolutions per output revolution; with the
    factory 25000 steps/rev and a 90:1 rotary table the resolution is
    1.6e-4° (Table 3.1).  The soft limits ``limits_deg`` (default: the light
    arm's 10°–175° from the camera) are also programmed into the controller
    (``LSPOS``/``LSNEG``, ``LS3``) as a second line of defence.

    >>> with Indexer(port=sim.port) as arm:        # doctest: +SKIP
    ...     arm.move_to(angle_deg=45.0)
    {'angle_deg': 45.0}
    """

    axes = ("angle_deg",)
    #: The simulator the ``gonio`` capture source starts for ``port: sim``.
    simulator = "sbrdf_devices.motors.sim.indexer:SimulatedIndexer"

    params = INDEXER

    def __init__(self, *, port: str, baudrate: int = 9600, timeout_s: float = 1.0, retries: int = 3,
                 tolerance_deg: float = 0.05, axis: int = 1, gear_ratio: float = 90.0,
                 limits_deg: Sequence[float] = (10.0, 175.0), speed_deg_s: float = 20.0,
                 acceleration_deg_s2: float = 40.0, move_timeout_s: float = 60.0, poll_s: float = 0.01):
        link = SerialLink(port, device="indexer", baudrate=baudrate, timeout_s=timeout_s, retries=retries)
        super().__init__(link, tolerance_deg=tolerance_deg, retries=retries)
        self.axis = int(axis)
        self.gear_ratio = float(gear_ratio)
        self.speed_deg_s = float(speed_deg_s)
        self.move_timeout_s = float(move_timeout_s)
        self.poll_s = float(poll_s)
        self._last: dict[str, float] = {}
        lo, hi = (float(v) for v in limits_deg)
        if lo > hi:
            link.close()
            raise ValueError(f"indexer on {port}: limits_deg {list(limits_deg)} is not [low, high]")
        n = self.axis
        try:
            for setup in ("ECHO0", "ERRLVL4", "COMEXC0", f"{n}MA1"):
                self._command(setup)
            self.steps_per_deg = self._resolution(f"{n}DRES", "drive resolution", DRES_RANGE) * self.gear_ratio / 360.0
            self.counts_per_deg = self._resolution(f"{n}ERES", "encoder resolution", ERES_RANGE) * self.gear_ratio / 360.0
            self.limits["angle_deg"] = (lo, hi)
            # The controller's own limits sit just outside ours: ours refuse first, its stop a runaway.
            margin = 2.0 * self.tolerance_deg
            self._set(f"{n}LSPOS", round((hi + margin) * self.steps_per_deg), "{:+d}", r"[+-]\d+", int)
            self._set(f"{n}LSNEG", round((lo - margin) * self.steps_per_deg), "{:+d}", r"[+-]\d+", int)
            self._command(f"{n}LS3")
            rev = 360.0 / self.gear_ratio
            self._set(f"{n}V", round(self.speed_deg_s / rev, 4), "{:.4f}", r"\d*\.?\d+", float)
            self._set(f"{n}A", round(acceleration_deg_s2 / rev, 4), "{:.4f}", r"\d*\.?\d+", float)
            self._last, _ = self._read_agreed(self.axes)
        except Exception:
            self.close()
            raise
        logger.info("indexer on %s axis %d: connected; %.4g steps/deg, soft limits %s", port, n, self.steps_per_deg,
                    self.limits["angle_deg"])

    # -- protocol ---------------------------------------------------------------------

    def _exchange(self, command: str, parse, timeout_s: float | None = None, retries: int | None = None):
        def checked(lines: Sequence[str]):
            if lines[-1].strip() == "?":
                message = " ".join(l.lstrip("*").strip() for l in lines[:-1]) or "error"
                raise DeviceRefused(f"controller refused: {message}", device="indexer", port=self.port,
                                    command=command, received="\n".join(lines))
            return parse(lines)

        return self.link.exchange(command, _is_prompt, checked, timeout_s=timeout_s, retries=retries)

    def _command(self, command: str, timeout_s: float | None = None, retries: int | None = None) -> None:
        def parse(lines: Sequence[str]) -> None:
            if len(lines) != 1:
                raise GarbledReply("expected only the prompt '>'", device="indexer", port=self.port,
                                   command=command, received="\n".join(lines))

        self._exchange(command, parse, timeout_s, retries)

    def _transfer(self, command: str, value_pattern: str) -> tuple[str, str]:
        """Send a reporting command; return the value text after its echoed name, and the raw line."""
        name = command.lstrip("!")
        pattern = re.compile(rf"^\*{re.escape(name)}(?P<value>{value_pattern})\s*$")

        def parse(lines: Sequence[str]) -> tuple[str, str]:
            data = [line for line in lines[:-1]]
            m = pattern.match(data[0]) if len(data) == 1 else None
            if not m:
                raise GarbledReply(f"expected '*{name}<value>' and the prompt '>'", device="indexer",
                                   port=self.port, command=command, received="\n".join(lines))
            return m.group("value"), data[0]

        value, self._raw = self._exchange(command, parse)
        return value, self._raw

    def _report(self, command: str) -> int:
        return int(self._transfer(command, r"\d+")[0])

    def _resolution(self, command: str, what: str, bounds: tuple[int, int]) -> int:
        lo, hi = bounds
        return self._verified(what, command, lambda: self._report(command),
                              lambda v: None if lo <= v <= hi else f"{v} per revolution is outside {lo}..{hi}")

    def _set(self, name: str, value, fmt: str, value_pattern: str, convert) -> None:
        """Send ``<name><value>``, read it back (``<name>``, twice in agreement); re-send once on a mismatch."""
        read = None
        for _ in range(2):
            self._command(f"{name}{fmt.format(value)}")
            read = self._verified(name, name, lambda: convert(self._transfer(name, value_pattern)[0]), lambda v: None)
            if abs(read - value) <= 1e-6 * max(1.0, abs(value)):
                return
        raise ImplausibleReply(f"{name} reads back {read} after setting {fmt.format(value)}", readings=[read],
                               device="indexer", port=self.port, command=name, received=self._raw)

    def _send_move(self, targets: dict[str, float]) -> None:
        n = self.axis
        self._command(f"{n}D{round(targets['angle_deg'] * self.steps_per_deg):+d}")
        self._command("GO" + "".join("1" if i == n else "0" for i in range(1, n + 1)))

    def _wait_for_move(self, targets: dict[str, float]) -> None:
        travel = abs(targets["angle_deg"] - self._last.get("angle_deg", targets["angle_deg"]))
        limit = min(self.move_timeout_s, self.link.timeout_s + 2.0 * travel / max(self.speed_deg_s, 1e-9))
        deadline = time.monotonic() + limit
        command = f"!{self.axis}TAS"
        while True:
            bits, raw = self._transfer(command, r"[01_]+")
            bits = bits.replace("_", "")
            if len(bits) != 32:
                raise GarbledReply("axis status must have 32 bits", device="indexer", port=self.port,
                                   command=command, received=raw)
            if bits[0] == "0":  # bit 1: motion in progress
                return
            if time.monotonic() > deadline:
                raise ReplyTimeout(f"axis {self.axis} still moving after {limit:.3g} s", device="indexer",
                                   port=self.port, command=command, received=raw)
            time.sleep(self.poll_s)

    def _position_command(self, axis: str) -> str:
        return f"!{self.axis}TPE"

    def _read_position(self, axes: tuple[str, ...]) -> tuple[dict[str, float], str]:
        value, raw = self._transfer(f"!{self.axis}TPE", r"[+-]\d+")
        out = {"angle_deg": int(value) / self.counts_per_deg}
        self._last.update(out)
        return out, raw

    def _halt(self, best_effort: bool) -> None:
        if best_effort:
            self._command("!S", timeout_s=min(self.link.timeout_s, 0.5), retries=0)
        else:
            self._command("!S")


def _is_prompt(line: str) -> bool:
    return line.strip() in _PROMPTS
