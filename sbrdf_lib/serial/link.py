"""A line-oriented serial link with timeouts, bounded retries and resynchronisation.

Both controllers on the rig speak checksumless ASCII: a command goes out, one
or more CR/LF-terminated lines come back.  Nothing in the bytes protects them,
so the link relies on three things instead:

* every exchange has a deadline (a dropped reply or a stalled controller is a
  :class:`~sbrdf_lib.serial.errors.ReplyTimeout`, never a hang);
* every reply is parsed strictly by the protocol module, which raises
  :class:`~sbrdf_lib.serial.errors.GarbledReply` for anything it does not expect, so
  line noise is detected rather than believed;
* all commands the drivers send are idempotent (absolute moves, queries,
  halts), so a failed exchange is retried by sending the command again, after
  draining whatever late bytes are still on the line.

An explicit error reply from the controller (:class:`DeviceRefused`) is not
retried: the controller heard the command and said no.  Neither is a failure
of the port itself (:class:`LinkLost`: ``OSError``, ``termios.error`` or a
``serial.SerialException`` from any read, write, flush or reconfiguration,
e.g. a USB adapter unplugged mid-capture): it names the device, the port and
the command, and the driver above halts what it still can and closes.

The protocol modules supply two callables per exchange: ``is_last(line)``
(does this line end the reply?) and ``parse(lines)``.
"""

from __future__ import annotations

import logging
import termios
import time
from collections.abc import Callable, Sequence
from typing import TypeVar

import serial

from .errors import DeviceClosed, DeviceError, DeviceRefused, GarbledReply, LinkLost, ReplyTimeout

__all__ = ["OS_LINK_ERRORS", "SerialLink", "os_reason"]

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: What the port raises when the device itself fails (a timeout is ``serial.SerialTimeoutException``, handled apart).
OS_LINK_ERRORS = (serial.SerialException, OSError, termios.error)


def os_reason(error: BaseException) -> str:
    """``termios.error(5, 'Input/output error')`` -> ``termios.error: [Errno 5] Input/output error``."""
    args: tuple = getattr(error, "args", ())
    if isinstance(error, termios.error) and len(args) == 2:
        return f"termios.error: [Errno {args[0]}] {args[1]}"
    return f"{type(error).__name__}: {error}"


class SerialLink:
    """One serial port, one command at a time.

    Parameters
    ----------
    port
        Device path (``/dev/ttyUSB0``, or a simulator's pty slave).
    device
        Name used in error messages (``ptu``, ``indexer``).
    baudrate, timeout_s
        Line speed, and how long to wait for a complete reply.
    retries
        Extra attempts after a timeout or garbled reply (0 = try once).
    terminator
        Appended to every command.
    """

    def __init__(self, port: str, *, device: str, baudrate: int = 9600, timeout_s: float = 1.0,
                 retries: int = 3, terminator: str = "\r\n"):
        self.port = port
        self.device = device
        self.baudrate = int(baudrate)
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.terminator = terminator
        #: Exchanges that needed more than one attempt, as ``(command, error)`` (diagnostics).
        self.recovered: list[tuple[str, str]] = []
        try:
            self._serial: serial.Serial | None = serial.Serial(port, baudrate=baudrate, timeout=self.timeout_s,
                                                               write_timeout=self.timeout_s)
        except (serial.SerialException, OSError) as e:
            raise DeviceError(f"cannot open serial port: {e}", device=device, port=port) from e
        logger.debug("%s: opened %s at %d baud", device, port, self.baudrate)

    # -- plumbing -----------------------------------------------------------------

    @property
    def is_open(self) -> bool:
        return self._serial is not None and self._serial.is_open

    def close(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            except OS_LINK_ERRORS:
                pass  # a port that is gone cannot be closed any further
            finally:
                self._serial = None

    def reopen(self) -> str | None:
        """Close the port and open it again (a device back under the same name); ``None``, or why it failed.

        Only for a best-effort halt after :class:`LinkLost`; a port that is
        really gone fails at once (``ENOENT``, or ``EIO`` for a pty whose master closed).
        """
        self.close()
        try:
            self._serial = serial.Serial(self.port, baudrate=self.baudrate, timeout=self.timeout_s,
                                         write_timeout=self.timeout_s)
        except (*OS_LINK_ERRORS, ValueError) as e:
            return os_reason(e)
        return None

    def _lost(self, what: str, error: BaseException, command: str | None, received: bytes | None = None) -> LinkLost:
        lost = LinkLost(f"serial link lost: {what} failed ({os_reason(error)}); the device disappeared "
                        "(unplugged, powered off or its port closed)", device=self.device, port=self.port,
                        command=command, received=received)
        lost.reason = f"{what} failed: {os_reason(error)}"
        return lost

    def _port(self, command: str | None = None) -> serial.Serial:
        if self._serial is None:
            raise DeviceClosed("the serial link is closed", device=self.device, port=self.port, command=command)
        return self._serial

    def write(self, command: str) -> None:
        """Send ``command`` + terminator, discarding any stale input first."""
        port = self._port(command)
        logger.debug("%s on %s: send %r", self.device, self.port, command)
        try:
            port.reset_input_buffer()
            port.write((command + self.terminator).encode("ascii"))
            port.flush()
        except serial.SerialTimeoutException as e:
            raise ReplyTimeout(f"write did not complete within {self.timeout_s:g} s", device=self.device,
                               port=self.port, command=command) from e
        except OS_LINK_ERRORS as e:
            raise self._lost("write", e, command) from e

    def read_line(self, command: str, deadline: float) -> str:
        """One line without its terminator, or :class:`ReplyTimeout` at ``deadline`` (``time.monotonic``)."""
        port = self._port(command)
        buf = bytearray()
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise ReplyTimeout(f"no complete reply within {self.timeout_s:g} s", device=self.device,
                                   port=self.port, command=command, received=bytes(buf) or None)
            try:
                port.timeout = remaining
                chunk = port.read_until(b"\n")
            except OS_LINK_ERRORS as e:
                raise self._lost("read", e, command, bytes(buf) or None) from e
            buf += chunk
            if buf.endswith(b"\n"):
                break
        raw = bytes(buf)
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            raise GarbledReply("reply is not ASCII", device=self.device, port=self.port, command=command,
                               received=raw) from None
        text = text.rstrip("\r\n")
        if any(not (c.isprintable() or c == "\t") for c in text):
            raise GarbledReply("reply has control characters", device=self.device, port=self.port,
                               command=command, received=raw)
        return text

    def drain(self, command: str | None = None) -> None:
        """Discard input until the line has been quiet for one timeout (bounded by three).

        A reply that was merely late (a stalled controller) then lands here
        instead of being taken for the answer to the next attempt.
        """
        port = self._port(command)
        quiet = max(self.timeout_s, 0.01)
        stop = time.monotonic() + 3 * self.timeout_s
        last = time.monotonic()
        try:
            while time.monotonic() < stop and time.monotonic() - last < quiet:
                port.timeout = min(quiet, max(stop - time.monotonic(), 0.0))
                if port.read(max(port.in_waiting, 1)):
                    last = time.monotonic()
            port.reset_input_buffer()
        except OS_LINK_ERRORS as e:
            raise self._lost("draining the input", e, command) from e

    # -- exchanges --------------------------------------------------------------------

    def read_reply(self, command: str, is_last: Callable[[str], bool], timeout_s: float | None = None,
                   skip_echo: bool = True) -> list[str]:
        """Lines up to and including the one ``is_last`` accepts; the echo of ``command`` is skipped."""
        deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
        lines: list[str] = []
        while True:
            line = self.read_line(command, deadline)
            if skip_echo and not lines and line.strip().upper() == command.strip().upper():
                continue
            lines.append(line)
            if is_last(line):
                logger.debug("%s on %s: reply to %r: %r", self.device, self.port, command, lines)
                return lines
            if len(lines) > 32:
                raise GarbledReply("reply does not end", device=self.device, port=self.port, command=command,
                                   received="\n".join(lines))

    def exchange(self, command: str, is_last: Callable[[str], bool], parse: Callable[[Sequence[str]], T],
                 timeout_s: float | None = None, retries: int | None = None) -> T:
        """Send ``command`` and parse its reply, retrying timeouts and garbled replies.

        Raises the last :class:`ReplyTimeout` / :class:`GarbledReply` (its
        message says how many attempts were made) when every attempt failed,
        and :class:`DeviceRefused` at once when the controller answers with an error.
        """
        attempts = 1 + (self.retries if retries is None else retries)
        last: DeviceError | None = None
        for attempt in range(attempts):
            try:
                self.write(command)
                value = parse(self.read_reply(command, is_last, timeout_s))
            except DeviceRefused:
                raise
            except (ReplyTimeout, GarbledReply) as e:
                last = e
                if self._serial is None:
                    break
                logger.info("%s on %s: attempt %d of %d for %r failed (%s); draining and retrying", self.device,
                            self.port, attempt + 1, attempts, command, _head(e))
                self.drain(command)
                continue
            if last is not None:
                self.recovered.append((command, str(last)))
            return value
        assert last is not None
        n = f"{attempts} attempt{'s' if attempts != 1 else ''}"
        raise type(last)(f"{_head(last)}; gave up after {n}", device=self.device, port=self.port,
                         command=command, received=last.received) from last


def _head(error: DeviceError) -> str:
    """The message of ``error`` without its ``device on port:`` prefix and detail suffix."""
    text = str(error)
    prefix = f"{error.device} on {error.port}: "
    if text.startswith(prefix):
        text = text[len(prefix):]
    cut = text.rfind(" (command ")
    return text[:cut] if cut >= 0 else text
