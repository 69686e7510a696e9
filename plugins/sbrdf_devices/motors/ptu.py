"""Driver for a pan-tilt unit speaking the Directed Perception PTU command language.

McAllister's rig used two Directed Perception PTU-46-70 units: one pans the
sample, the other tilts and rolls it (seed 000, §3.3, Table 3.1).  The
controller speaks a terse ASCII language (DP "PTU command set", also used by
the later FLIR PTU-D46/E-series); the subset this driver uses:

============  =======================================  ===========================================
command       meaning                                  reply (verbose feedback, ``FV``)
============  =======================================  ===========================================
``PP<n>``     pan to absolute position ``n``           ``*`` or ``! Maximum allowable Pan position is 3090``
``TP<n>``     tilt to absolute position ``n``          ``*`` or ``! ...``
``PP``/``TP`` query position                           ``* Current Pan position is 1234``
``PS<n>``     pan speed, positions/s (``TS`` tilt)     ``*``
``PN``/``PX`` pan min / max position (``TN``/``TX``)   ``* Minimum Pan position is -12360``
``PR``/``TR`` resolution                               ``* 46.2857 seconds arc per position``
``A``         await: reply only when motion is done    ``*``
``H``         halt both axes                           ``*``
``ED``        echo disable (factory default: enabled)  ``*``
``FV``        verbose feedback                         ``*``
``I``         immediate (not slaved) execution         ``*``
============  =======================================  ===========================================

Commands are delimited by whitespace (this driver ends each with CR LF);
every reply is one line, ``*`` for success and ``!`` for an error.  Positions
are integer steps; the resolution query converts them to degrees (a
PTU-46-70 in eighth-step mode has 46.2857 arc-seconds per position, the
0.0129° of Table 3.1).

The driver keeps the controller in verbose mode so that a position reply
names its axis: a stale ``Tilt`` reply arriving for a ``PP`` query is
detected as garbled instead of being read as the pan position.

What is verified (a digit changed by line noise keeps a reply valid ASCII):

* the resolution (``PR``/``TR``) is read until two readings in a row agree,
  and must be one of the controller model's resolutions (``resolutions_arcsec``;
  default the PTU-46 family: 185.1428″/2^k for full to 1/32 steps, which
  includes the PTU-46-70's 46.2857″); ``46.2857`` read once as ``41.2857``
  costs one extra query, a persistent wrong value is an
  :class:`~sbrdf_lib.serial.errors.ImplausibleReply` before anything moves;
* the factory limits (``PN``/``PX``/``TN``/``TX``) likewise must agree twice,
  with minimum < maximum within ±360°;
* each speed (``PS<n>``) is read back (``PS``) and must equal what was sent
  (re-sent once if not);
* every move is read back (:class:`~sbrdf_lib.serial.controller.MotorController`).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from functools import partial

from sbrdf_lib.serial.controller import MotorController
from sbrdf_lib.serial.errors import DeviceRefused, GarbledReply, ImplausibleReply
from sbrdf_lib.serial.link import SerialLink

from ..declarations import PTU, PTU46_RESOLUTIONS_ARCSEC

logger = logging.getLogger(__name__)

_AXIS = {"pan_deg": ("P", "Pan"), "tilt_deg": ("T", "Tilt")}
_ACK = re.compile(r"^\*\s*$")
_NUMBER_REPLY = r"^\*\s*(?:{phrase}\s+)?(?P<value>[-+]?\d+)\s*$"
_RESOLUTION = re.compile(r"^\*\s*(?P<value>\d*\.?\d+)\s+seconds arc per position\s*$")
#: Relative tolerance when matching a reported resolution (the unit prints four decimals).
RESOLUTION_RTOL = 2e-4


class PanTiltUnit(MotorController):
    """A Directed Perception-style pan-tilt unit on a serial port.

    Opens the port and configures the unit on construction (echo off, verbose
    feedback, immediate mode, speeds), reads its resolution and factory limits;
    the soft limits are the intersection of those and ``pan_limits_deg`` /
    ``tilt_limits_deg``.

    >>> with PanTiltUnit(port=sim.port) as ptu:          # doctest: +SKIP
    ...     ptu.move_to(pan_deg=30.0, tilt_deg=-10.0)
    ...     ptu.position()
    {'pan_deg': 30.0, 'tilt_deg': -10.0}
    """

    axes = ("pan_deg", "tilt_deg")
    #: The simulator the ``gonio`` capture source starts for ``port: sim``.
    simulator = "sbrdf_devices.motors.sim.ptu:SimulatedPTU"

    params = PTU

    def __init__(self, *, port: str, baudrate: int = 9600, timeout_s: float = 1.0, retries: int = 3,
                 tolerance_deg: float = 0.05, pan_limits_deg: Sequence[float] = (-159.0, 159.0),
                 tilt_limits_deg: Sequence[float] = (-47.0, 31.0), speed_deg_s: float = 20.0,
                 move_timeout_s: float = 60.0, resolutions_arcsec: Sequence[float] | None = PTU46_RESOLUTIONS_ARCSEC):
        link = SerialLink(port, device="ptu", baudrate=baudrate, timeout_s=timeout_s, retries=retries)
        super().__init__(link, tolerance_deg=tolerance_deg, retries=retries)
        self.speed_deg_s = float(speed_deg_s)
        self.move_timeout_s = float(move_timeout_s)
        self.arcsec_per_step: dict[str, float] = {}
        self.resolutions_arcsec = tuple(float(v) for v in (resolutions_arcsec or ()))
        self._last: dict[str, float] = {}
        try:
            for setup in ("ED", "FV", "I"):
                self._ack(setup)
            user = {"pan_deg": pan_limits_deg, "tilt_deg": tilt_limits_deg}
            for axis, (letter, word) in _AXIS.items():
                self.arcsec_per_step[axis] = self._verified(
                    f"{word.lower()} resolution", f"{letter}R", partial(self._query, f"{letter}R", _RESOLUTION, float),
                    self._check_resolution)
                lo_steps = self._factory_limit(axis, letter, word, "N", "Minimum")
                hi_steps = self._factory_limit(axis, letter, word, "X", "Maximum")
                if lo_steps >= hi_steps:
                    raise ImplausibleReply(f"{word.lower()} factory limits read as [{lo_steps}, {hi_steps}] positions: "
                                           "minimum is not below maximum", readings=[lo_steps, hi_steps], device="ptu",
                                           port=self.port, command=f"{letter}N/{letter}X", received=self._raw)
                lo, hi = self._steps_to_deg(axis, lo_steps), self._steps_to_deg(axis, hi_steps)
                ulo, uhi = (float(v) for v in user[axis])
                if ulo > uhi:
                    raise ValueError(f"ptu on {port}: {axis[:-4]}_limits_deg {list(user[axis])} is not [low, high]")
                self.limits[axis] = (max(lo, ulo), min(hi, uhi))
                speed = max(1, round(self.speed_deg_s * 3600.0 / self.arcsec_per_step[axis]))
                self._set_speed(letter, word, speed)
            self._last, _ = self._read_agreed(self.axes)
        except Exception:
            self.close()
            raise
        logger.info("ptu on %s: connected; arcsec/step %s, soft limits %s", port, self.arcsec_per_step, self.limits)

    # -- verification ------------------------------------------------------------------

    def _check_resolution(self, value: float) -> str | None:
        if not value > 0:
            return f"{value} arc-seconds per position is not positive"
        known = self.resolutions_arcsec
        if known and not any(abs(value - r) <= RESOLUTION_RTOL * r for r in known):
            return (f"{value:g} arc-seconds per position is none of the controller model's resolutions "
                    f"({', '.join(str(r) for r in known)}; set resolutions_arcsec for another model)")
        return None

    def _factory_limit(self, axis: str, letter: str, word: str, code: str, side: str) -> int:
        command, pattern = f"{letter}{code}", _number(f"{side} {word} position is")

        def check(steps: int) -> str | None:
            deg = self._steps_to_deg(axis, steps)
            return None if abs(deg) <= 360.0 else f"{steps} positions is {deg:.1f} deg, beyond a full turn"

        return self._verified(f"{word.lower()} {side.lower()} position", command,
                              lambda: self._query(command, pattern, int), check)

    def _set_speed(self, letter: str, word: str, speed: int) -> None:
        """``PS<n>``, then read it back; a mismatch (the command garbled on the way) is re-sent once."""
        query = f"{letter}S"
        read = None
        for _ in range(2):
            self._ack(f"{letter}S{speed}")
            read = self._verified(f"{word.lower()} speed", query,
                                  lambda: self._query(query, _number(f"Target {word} speed is"), int),
                                  lambda v: None if v > 0 else f"speed {v} is not positive")
            if read == speed:
                return
        raise ImplausibleReply(f"{word.lower()} speed reads back {read} positions/s after setting {speed}",
                               readings=[read], device="ptu", port=self.port, command=query, received=self._raw)

    # -- protocol --------------------------------------------------------------------

    def _steps_to_deg(self, axis: str, steps: int) -> float:
        return steps * self.arcsec_per_step[axis] / 3600.0

    def _deg_to_steps(self, axis: str, degrees: float) -> int:
        return round(degrees * 3600.0 / self.arcsec_per_step[axis])

    def _ack(self, command: str, timeout_s: float | None = None, retries: int | None = None) -> None:
        def parse(lines: Sequence[str]) -> None:
            _refused(self, command, lines[-1])
            if not _ACK.match(lines[-1]):
                raise GarbledReply("expected '*'", device="ptu", port=self.port, command=command, received=lines[-1])

        self.link.exchange(command, _one_line, parse, timeout_s=timeout_s, retries=retries)

    def _query(self, command: str, pattern: re.Pattern, convert):
        def parse(lines: Sequence[str]):
            _refused(self, command, lines[-1])
            m = pattern.match(lines[-1])
            if not m:
                raise GarbledReply(f"reply does not match {pattern.pattern!r}", device="ptu", port=self.port,
                                   command=command, received=lines[-1])
            return convert(m.group("value")), lines[-1]

        value, self._raw = self.link.exchange(command, _one_line, parse)
        return value

    def _send_move(self, targets: dict[str, float]) -> None:
        for axis, degrees in targets.items():
            self._ack(f"{_AXIS[axis][0]}P{self._deg_to_steps(axis, degrees)}")

    def _wait_for_move(self, targets: dict[str, float]) -> None:
        travel = max(abs(v - self._last.get(k, v)) for k, v in targets.items())
        expected = travel / max(self.speed_deg_s, 1e-9)
        self._ack("A", timeout_s=min(self.move_timeout_s, self.link.timeout_s + 2.0 * expected))

    def _position_command(self, axis: str) -> str:
        return f"{_AXIS[axis][0]}P"

    def _read_position(self, axes: tuple[str, ...]) -> tuple[dict[str, float], str]:
        out, raws = {}, []
        for axis in axes:
            letter, word = _AXIS[axis]
            steps = self._query(f"{letter}P", _number(f"Current {word} position is"), int)
            out[axis] = self._steps_to_deg(axis, steps)
            raws.append(self._raw)
        self._last.update(out)
        return out, " | ".join(raws)

    def _halt(self, best_effort: bool) -> None:
        if best_effort:
            self._ack("H", timeout_s=min(self.link.timeout_s, 0.5), retries=0)
        else:
            self._ack("H")


def _one_line(line: str) -> bool:
    return True


def _number(phrase: str) -> re.Pattern:
    return re.compile(_NUMBER_REPLY.format(phrase=re.escape(phrase)))


def _refused(driver: PanTiltUnit, command: str, line: str) -> None:
    if line.startswith("!"):
        raise DeviceRefused(f"controller refused: {line[1:].strip() or 'error'}", device="ptu", port=driver.port,
                            command=command, received=line)
