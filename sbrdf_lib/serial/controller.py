"""What every motor-controller driver does the same way: limits, verified moves, clean stops.

A capture source drives several controllers (a pan-tilt unit for pan, another
for tilt and roll, an indexer for the light arm) through one small API:

``move_to(**targets)``
    Blocking, absolute, in degrees; keyword names are the driver's
    :attr:`MotorController.axes` (``pan_deg``, ``tilt_deg``; ``angle_deg``).
    Targets outside the soft limits raise :class:`SoftLimitError` before a
    byte is sent.  After the motion the position is read back; a miss larger
    than ``tolerance_deg`` re-commands the move, up to ``retries`` times, then
    raises :class:`PositionError`.
``position()``
    The read-back position, with the same keys (``move_to(**position())`` is a no-op).
``stop()`` / ``close()`` / ``with``
    Halt motion; halt and release the port.

A failure that ends the session (a reply that never comes after every retry,
an error reply, a persistent position miss, the port vanishing) halts the
motors, closes the port and re-raises: a driver in an unknown state must not
keep moving hardware.  When the port itself is gone (:class:`LinkLost`) the
halt is still attempted (best effort) and the error says whether it got
through, and what the driver was doing (``moving to pan_deg=20.0000``).

Values that can be verified are: constants the drivers read at connection
(resolutions, factory limits) are queried until two readings in a row agree
and pass the controller model's checks (:meth:`MotorController._verified`),
settings are read back after they are sent, and every move is read back
until two readings in a row agree (:meth:`MotorController._read_agreed`).
Line noise that turns one digit into another keeps a reply valid ASCII, so
only a repeated, cross-checked reading catches it (:class:`ImplausibleReply`).
The protocol drivers implement only the ``_send_move``, ``_wait_for_move``,
``_read_position`` and ``_halt`` hooks.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import TypeVar

from ..serial_params import LINK_PARAMS
from .errors import DeviceClosed, DeviceError, ImplausibleReply, LinkLost, PositionError, SoftLimitError
from .link import SerialLink, _head

__all__ = ["LINK_PARAMS", "MotorController"]

logger = logging.getLogger(__name__)

T = TypeVar("T")


class MotorController:
    """Base class of the serial motor-controller drivers (see the module docstring)."""

    #: Keyword names accepted by :meth:`move_to` and returned by :meth:`position`.
    axes: tuple[str, ...] = ()

    def __init__(self, link: SerialLink, *, tolerance_deg: float, retries: int):
        self.link = link
        self.tolerance_deg = float(tolerance_deg)
        self.retries = int(retries)
        #: Soft limits in degrees per axis, filled in by the protocol driver when it connects.
        self.limits: dict[str, tuple[float, float]] = {}
        #: Moves that needed re-commanding after a position miss, as ``(axis, target, read)``.
        self.position_misses: list[tuple[str, float, float]] = []
        #: Verified queries that needed more than two readings, as ``(what, readings)`` (diagnostics).
        self.reread: list[tuple[str, list]] = []
        #: Outcome of the last halt attempted by :meth:`close`: ``None`` (none yet), ``""`` (acknowledged)
        #: or why it failed.
        self.halt_outcome: str | None = None
        #: Whether that halt got through only after reopening a port that had vanished.
        self.halt_reopened = False

    # -- public API -------------------------------------------------------------------

    @property
    def port(self) -> str:
        return self.link.port

    @property
    def is_open(self) -> bool:
        return self.link.is_open

    def move_to(self, **targets: float) -> dict[str, float]:
        """Move to absolute ``targets`` (degrees), wait, verify; return the read-back position."""
        self._require_open("move")
        targets = self._check_targets(targets)
        reply = None
        logger.debug("%s on %s: move to %s", self.link.device, self.port, targets)
        for _attempt in range(1 + self.retries):
            try:
                self._send_move(targets)
                self._wait_for_move(targets)
                read, reply = self._read_agreed(tuple(targets))
            except DeviceError as e:
                self._fail(e, doing="moving to " + ", ".join(f"{k}={v:.4f}" for k, v in targets.items()))
            off = {k: read[k] - v for k, v in targets.items() if abs(read[k] - v) > self.tolerance_deg}
            if not off:
                return self._full_position(read)
            logger.info("%s on %s: position miss %s after moving to %s; re-commanding", self.link.device,
                        self.port, off, targets)
            for k in off:
                self.position_misses.append((k, targets[k], read[k]))
        worst = max(off, key=lambda k: abs(off[k]))
        self._fail(PositionError(
            f"{worst} read back {read[worst]:.4f} deg after moving to {targets[worst]:.4f} deg "
            f"(off by {off[worst]:+.4f}, tolerance {self.tolerance_deg:g} deg) on {1 + self.retries} attempts; "
            "motion halted and port closed",
            device=self.link.device, port=self.port, command=self._position_command(worst), received=reply))
        raise AssertionError("unreachable")  # pragma: no cover

    def position(self) -> dict[str, float]:
        """Current position of every axis in degrees, keyed like :meth:`move_to`."""
        self._require_open("position")
        try:
            read, _ = self._read_agreed(self.axes)
        except DeviceError as e:
            self._fail(e, doing="reading the position")
        return read

    def _read_agreed(self, axes: tuple[str, ...]) -> tuple[dict[str, float], str]:
        """The position of ``axes`` read until two readings in a row agree (the motors are at rest).

        A digit changed by line noise keeps a position reply valid ASCII and,
        in the last digits, inside the move tolerance: read once, it would be
        recorded as the pose.  A second query costs one short exchange per
        move; a disagreement costs one more, up to ``3 + link.retries``
        readings, then :class:`ImplausibleReply` lists them.
        """
        limit = max(2, 3 + self.link.retries)
        readings: list[dict[str, float]] = []
        reply = ""
        for _ in range(limit):
            read, reply = self._read_position(axes)
            if readings and read == readings[-1]:
                if len(readings) > 1:
                    self.reread.append(("position", readings + [read]))
                return read, reply
            readings.append(read)
        shown = ", ".join(str(r) for r in readings)
        raise ImplausibleReply(f"position: {len(readings)} readings ({shown}) never agreed twice in a row while the "
                               f"motors were at rest (line noise changing digits?)", readings=readings,
                               device=self.link.device, port=self.port, command=self._position_command(axes[0]),
                               received=reply)

    def stop(self) -> None:
        """Halt all motion now (raises if the controller does not acknowledge)."""
        self._require_open("stop")
        try:
            self._halt(best_effort=False)
        except DeviceError as e:
            self._fail(e, doing="halting")

    def close(self) -> None:
        """Halt motion (best effort) and release the port; safe to call twice."""
        if not self.link.is_open:
            return
        try:
            self._halt(best_effort=True)
            self.halt_outcome = ""
        except LinkLost as e:
            # The port is gone.  A device that came straight back under the same name (a USB glitch) can
            # still be halted through a fresh port; one that is really gone fails to open at once.
            self.halt_outcome = e.reason or _head(e)
            problem = self.link.reopen()
            if problem is not None:
                self.halt_outcome += f"; reopening {self.port} failed: {problem}"
            else:
                try:
                    self._halt(best_effort=True)
                    self.halt_outcome = ""
                    self.halt_reopened = True
                except Exception as again:  # noqa: BLE001 - best effort
                    self.halt_outcome += f"; after reopening {self.port}: {getattr(again, 'reason', '') or again}"
        except DeviceError as e:
            self.halt_outcome = getattr(e, "reason", None) or _head(e)
        except Exception as e:  # noqa: BLE001 - closing must release the port whatever the halt raised
            self.halt_outcome = f"{type(e).__name__}: {e}"
        finally:
            self.link.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "open" if self.is_open else "closed"
        return f"{type(self).__name__}(port={self.port!r}, {state})"

    # -- helpers for subclasses -------------------------------------------------------

    def _check_targets(self, targets: Mapping[str, float]) -> dict[str, float]:
        unknown = sorted(set(targets) - set(self.axes))
        if unknown or not targets:
            raise SoftLimitError(f"move_to needs keyword targets among {list(self.axes)}, got {sorted(targets)}",
                                 device=self.link.device, port=self.port)
        checked = {}
        for name, value in targets.items():
            value = float(value)
            lo, hi = self.limits[name]
            if not (lo <= value <= hi):  # also rejects NaN
                raise SoftLimitError(f"{name}={value:g} deg is outside the soft limits [{lo:g}, {hi:g}] deg; "
                                     "nothing was sent", device=self.link.device, port=self.port)
            checked[name] = value
        return checked

    def _full_position(self, read: dict[str, float]) -> dict[str, float]:
        if set(read) == set(self.axes):
            return read
        rest, _ = self._read_agreed(tuple(a for a in self.axes if a not in read))
        return {a: {**read, **rest}[a] for a in self.axes}

    def _require_open(self, what: str) -> None:
        if not self.link.is_open:
            raise DeviceClosed(f"cannot {what}: the driver is closed", device=self.link.device, port=self.port)

    def _fail(self, error: DeviceError, doing: str | None = None):
        """Halt (best effort), close the port, raise ``error``.

        A lost link is re-raised with what the driver was ``doing`` and whether
        the halt got through (it cannot when the port is gone; a capture source
        halts its other motors).
        """
        self.close()
        if isinstance(error, LinkLost):
            halt = (f"halt acknowledged{' after reopening the port' if self.halt_reopened else ''}"
                    if self.halt_outcome == "" else
                    f"halt could not be sent ({self.halt_outcome})" if self.halt_outcome else "halt not attempted")
            lost = LinkLost(f"{_head(error)}{' while ' + doing if doing else ''}; {halt}; port closed",
                            device=error.device, port=error.port, command=error.command, received=error.received)
            lost.reason = error.reason
            raise lost from error
        raise error

    def _verified(self, what: str, command: str, read: Callable[[], T], check: Callable[[T], str | None],
                  reads: int | None = None) -> T:
        """A constant read until two readings in a row agree and ``check`` finds nothing wrong.

        ``read()`` queries the controller once (its reply already parsed
        strictly); ``check(value)`` returns why a value cannot be right for
        the controller model, or ``None``.  Up to ``reads`` readings (default
        ``3 + link.retries``) are taken; then :class:`ImplausibleReply` lists
        them.  One corrupted reading among good ones costs one extra query.
        """
        limit = max(2, 3 + self.link.retries if reads is None else int(reads))
        readings: list = []
        problem = None
        for _ in range(limit):
            value = read()
            readings.append(value)
            problem = check(value)
            if problem is None and len(readings) >= 2 and readings[-1] == readings[-2]:
                if len(readings) > 2:
                    self.reread.append((what, readings))
                return value
        shown = ", ".join(str(v) for v in readings)
        reason = f"; the last is implausible: {problem}" if problem else " (line noise changing digits?)"
        raise ImplausibleReply(f"{what}: {len(readings)} readings ({shown}) never gave the same plausible value "
                               f"twice in a row{reason}", readings=readings, device=self.link.device,
                               port=self.port, command=command, received=getattr(self, "_raw", None))

    # -- protocol hooks -----------------------------------------------------------------

    def _send_move(self, targets: dict[str, float]) -> None:
        raise NotImplementedError

    def _wait_for_move(self, targets: dict[str, float]) -> None:
        raise NotImplementedError

    def _read_position(self, axes: tuple[str, ...]) -> tuple[dict[str, float], str]:
        """Positions of ``axes`` in degrees, and the raw reply (for error messages)."""
        raise NotImplementedError

    def _position_command(self, axis: str) -> str:
        raise NotImplementedError

    def _halt(self, best_effort: bool) -> None:
        raise NotImplementedError
