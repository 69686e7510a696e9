"""turntable: driver for a rotary stage speaking a three-command ASCII protocol.

The example of a device plugin.  The protocol is deliberately tiny, so that
what a driver must get right stands out: strict parsing, a deadline on every
reply, idempotent commands (so a failed exchange can be re-sent), and a halt
on every failure.

=============  ===========================================  ==========================================
command        meaning                                      reply
=============  ===========================================  ==========================================
``G<deg>``     go to the absolute angle (three decimals)    ``OK``, or ``ERR <reason>`` (not moved)
``Q``          query angle and state                        ``Q +045.000 IDLE`` / ``Q +012.345 MOVING``
``S``          stop now                                     ``OK``
=============  ===========================================  ==========================================

Commands and replies end with CR LF; the stage does not echo.  The position
reply repeats its command letter, so a late ``OK`` arriving for a ``Q`` is
recognised as garbled instead of being read as a position.

The serial plumbing (timeouts, retries, resynchronisation) is
:class:`sbrdf_lib.serial.SerialLink`; limits, verified moves and clean stops
are :class:`sbrdf_lib.serial.MotorController`, both from sbrdf's public
library layer.  This module only declares its parameters and implements the
protocol hooks.  :mod:`sbrdf_example.turntable_sim` serves the same protocol
on a pseudo-terminal, with injectable faults.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Sequence

from sbrdf_lib.serial import DeviceRefused, GarbledReply, MotorController, ReplyTimeout, SerialLink

from .declarations import TURNTABLE

__all__ = ["Turntable"]

logger = logging.getLogger(__name__)

_QUERY = re.compile(r"^Q (?P<angle>[+-]\d+\.\d{3}) (?P<state>MOVING|IDLE)$")


class Turntable(MotorController):
    """One rotary stage on a serial port, in degrees; axis ``angle_deg``.

    Connecting sends one ``Q``: a port with something else on it fails here,
    with the reply in the message, rather than at the first move.
    """

    axes = ("angle_deg",)
    #: The simulator the ``gonio`` capture source starts for ``port: sim``.
    simulator = "sbrdf_example.turntable_sim:SimulatedTurntable"

    params = TURNTABLE

    def __init__(self, *, port: str, baudrate: int = 19200, timeout_s: float = 1.0, retries: int = 3,
                 tolerance_deg: float = 0.01, limits_deg: Sequence[float] = (-180.0, 180.0),
                 move_timeout_s: float = 60.0, poll_s: float = 0.005):
        lo, hi = (float(v) for v in limits_deg)
        if not lo <= hi:
            raise ValueError(f"turntable on {port}: limits_deg {list(limits_deg)} is not [low, high]")
        link = SerialLink(port, device="turntable", baudrate=baudrate, timeout_s=timeout_s, retries=retries)
        super().__init__(link, tolerance_deg=tolerance_deg, retries=retries)
        self.limits["angle_deg"] = (lo, hi)
        self.move_timeout_s = float(move_timeout_s)
        self.poll_s = float(poll_s)
        try:
            angle, moving, _ = self._query()
        except Exception:
            self.close()
            raise
        logger.info("turntable on %s: connected at %.3f deg%s", port, angle, " (moving)" if moving else "")

    # -- protocol ---------------------------------------------------------------------

    def _exchange(self, command: str, parse, timeout_s: float | None = None, retries: int | None = None):
        def checked(lines: Sequence[str]):
            if lines[0].startswith("ERR"):
                raise DeviceRefused(f"stage refused: {lines[0][3:].strip() or 'error'}", device="turntable",
                                    port=self.port, command=command, received=lines[0])
            return parse(lines[0])

        return self.link.exchange(command, lambda line: True, checked, timeout_s=timeout_s, retries=retries)

    def _ok(self, command: str, timeout_s: float | None = None, retries: int | None = None) -> None:
        def parse(line: str) -> None:
            if line != "OK":
                raise GarbledReply("expected 'OK'", device="turntable", port=self.port, command=command, received=line)

        self._exchange(command, parse, timeout_s, retries)

    def _query(self) -> tuple[float, bool, str]:
        """``(angle_deg, moving, raw reply)``."""
        def parse(line: str) -> tuple[float, bool, str]:
            m = _QUERY.match(line)
            if not m:
                raise GarbledReply("expected 'Q <angle> MOVING|IDLE'", device="turntable", port=self.port,
                                   command="Q", received=line)
            return float(m["angle"]), m["state"] == "MOVING", line

        return self._exchange("Q", parse)

    def _send_move(self, targets: dict[str, float]) -> None:
        self._ok(f"G{targets['angle_deg']:+.3f}")

    def _wait_for_move(self, targets: dict[str, float]) -> None:
        deadline = time.monotonic() + self.move_timeout_s
        while True:
            _, moving, raw = self._query()
            if not moving:
                return
            if time.monotonic() > deadline:
                raise ReplyTimeout(f"still moving after {self.move_timeout_s:g} s", device="turntable",
                                   port=self.port, command="Q", received=raw)
            time.sleep(self.poll_s)

    def _read_position(self, axes: tuple[str, ...]) -> tuple[dict[str, float], str]:
        angle, _, raw = self._query()
        return {"angle_deg": angle}, raw

    def _position_command(self, axis: str) -> str:
        return "Q"

    def _halt(self, best_effort: bool) -> None:
        if best_effort:  # closing after a failure: one short try, the port is released either way
            self._ok("S", timeout_s=min(self.link.timeout_s, 0.5), retries=0)
        else:
            self._ok("S")
