"""A controller simulator on a pseudo-terminal, with fault injection, and a simulated motor axis.

Why a pty and not a mock: the drivers' failure handling (timeouts, partial
lines, bytes that are not ASCII, replies that arrive after the driver gave up)
lives in pyserial reads and writes.  A pty gives the driver a real serial
device path; a thread on the master end plays the controller.

Faults are data (:class:`Fault`), matched against each received command with
a regular expression, and are either transient (``times=N``) or persistent
(``times=None``):

``drop``
    The command is executed but no reply is sent.
``garble``
    The reply is sent with bytes replaced by line noise (non-ASCII and
    control bytes, so a strict parser must notice).
``stall``
    The controller goes silent for ``stall_s`` seconds, then sends the reply
    (late) and works through whatever queued up meanwhile.
``miss``
    A move command ends ``miss_deg`` away from its target (the encoder
    reports where the motor really is).
``corrupt``
    Line noise that stays valid ASCII: the reply is sent with one digit
    changed into another (the ``digit``-th digit of the reply, counted from 0,
    becomes ``(d + 5) mod 10``), so ``* 46.2857 seconds arc per position``
    arrives as ``* 41.2857 ...``; only a repeated, cross-checked query can tell.
``vanish``
    The device disappears when the command arrives (a USB adapter pulled
    out, the controller powered off): the simulator closes its end of the
    pty without replying, and every later read or write on the port fails
    with an I/O error (``termios.error`` / ``OSError`` / ``SerialException``).
    :meth:`PtySimulator.unplug` does the same at any moment.
"""

from __future__ import annotations

import os
import re
import select
import threading
import time
import tty
from dataclasses import dataclass, field

__all__ = ["FAULT_KINDS", "REPLY_FAULTS", "Fault", "PtySimulator", "SimulatedAxis", "corrupt", "garble"]

FAULT_KINDS = ("drop", "garble", "stall", "miss", "corrupt", "vanish")
REPLY_FAULTS = ("drop", "garble", "stall", "corrupt", "vanish")


@dataclass
class Fault:
    """One injected fault (see the module docstring for the kinds).

    Parameters
    ----------
    kind
        ``drop``, ``garble``, ``stall`` or ``miss``.
    match
        Regular expression that must match the whole received command
        (upper-case, as sent, e.g. ``PP`` for the pan position query,
        ``PP-?\\d+`` for pan moves, ``!1TPE``); default: every command.
    times
        How many times the fault fires; ``None`` = persistent.
    skip
        Matching commands to let through before the fault fires.
    stall_s
        Silence before a stalled reply.
    miss_deg
        How far a missed move ends from its target (signed).
    digit
        Which digit of the reply a ``corrupt`` fault changes (0 = the first).
    """

    kind: str
    match: str = ".*"
    times: int | None = 1
    skip: int = 0
    stall_s: float = 0.5
    miss_deg: float = 1.0
    digit: int = 1
    seen: int = field(default=0, init=False)
    fired: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r}; use one of {list(FAULT_KINDS)}")
        self._pattern = re.compile(self.match, re.IGNORECASE)

    @property
    def persistent(self) -> bool:
        return self.times is None

    def take(self, command: str) -> bool:
        """Count a matching command; ``True`` when the fault fires for it."""
        if not self._pattern.fullmatch(command):
            return False
        self.seen += 1
        if self.seen <= self.skip or (self.times is not None and self.fired >= self.times):
            return False
        self.fired += 1
        return True


class SimulatedAxis:
    """A stepper axis moving at constant speed, in (fractional) steps.

    ``time_scale`` shrinks simulated travel times (0.002 turns a 10 s move
    into 20 ms) and ``max_move_s`` caps them, so tests stay fast but motion
    still takes time, and "await" and "is moving" are exercised for real.
    """

    def __init__(self, position: float = 0.0, speed: float = 1000.0, time_scale: float = 0.002,
                 max_move_s: float = 0.05):
        self.speed = float(speed)
        self.time_scale = float(time_scale)
        self.max_move_s = float(max_move_s)
        self._from = self._to = float(position)
        self._t0 = 0.0
        self._duration = 0.0
        self.lock = threading.Lock()

    def move(self, target: float, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        with self.lock:
            start = self._position(now)
            self._from, self._to, self._t0 = start, float(target), now
            self._duration = min(abs(self._to - start) / max(self.speed, 1e-9) * self.time_scale, self.max_move_s)

    def _position(self, now: float) -> float:
        if self._duration <= 0 or now >= self._t0 + self._duration:
            return self._to
        return self._from + (self._to - self._from) * (now - self._t0) / self._duration

    def position(self, now: float | None = None) -> float:
        with self.lock:
            return self._position(time.monotonic() if now is None else now)

    def moving(self, now: float | None = None) -> bool:
        now = time.monotonic() if now is None else now
        with self.lock:
            return self._duration > 0 and now < self._t0 + self._duration

    def halt(self) -> None:
        now = time.monotonic()
        with self.lock:
            self._from = self._to = self._position(now)
            self._duration = 0.0

    @property
    def target(self) -> float:
        return self._to


class PtySimulator:
    """Base of the controller simulators: a pty, a serving thread, fault bookkeeping.

    Subclasses implement :meth:`handle` (one command in, reply text out) and
    may override :meth:`split` (how the byte stream is cut into commands).
    ``received`` lists every command as it arrived, for tests that must prove
    something was (or was not) sent.
    """

    eol = "\r\n"

    def __init__(self, faults=(), echo: bool = True, time_scale: float = 0.002, max_move_s: float = 0.05):
        self.faults: list[Fault] = list(faults)
        self.echo = echo
        self.time_scale = time_scale
        self.max_move_s = max_move_s
        self.received: list[str] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master = self._slave = -1
        self.port = ""
        self.error: BaseException | None = None
        self.unplugged = False

    # -- lifecycle --------------------------------------------------------------------

    def start(self):
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no line discipline: the bytes the driver writes are the bytes we read
        self.port = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._serve, name=f"{type(self).__name__}({self.port})", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        for fd in (self._master, self._slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = -1

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def unplug(self) -> None:
        """The device disappears: the master end of the pty closes and nothing answers any more.

        The driver's port (the slave) then fails every read, write and flush
        with an I/O error, as a serial adapter does when it is pulled out.
        Safe from any thread; :meth:`stop` still cleans up.
        """
        self.unplugged = True
        if self._thread is None or threading.current_thread() is self._thread:
            self._close_master()
        else:
            self._thread.join(timeout=5)  # the serving thread closes the master at its next poll
            self._thread = None
            self._close_master()

    def _close_master(self) -> None:
        if self._master >= 0:
            try:
                os.close(self._master)
            except OSError:
                pass
            self._master = -1

    def add_fault(self, fault: Fault) -> Fault:
        """Inject a fault while running (e.g. after the driver has connected)."""
        self.faults.append(fault)
        return fault

    # -- protocol hooks -------------------------------------------------------------

    def split(self, buffer: str) -> tuple[list[str], str]:
        """Cut complete commands off ``buffer``; default: CR/LF-terminated lines."""
        *lines, rest = re.split(r"[\r\n]", buffer)
        return [line.strip() for line in lines if line.strip()], rest

    def handle(self, command: str) -> str | None:
        """The reply to ``command`` without the final line end (``None``: no reply)."""
        raise NotImplementedError

    def take_fault(self, kinds: tuple[str, ...], command: str) -> Fault | None:
        for fault in self.faults:
            if fault.kind in kinds and fault.take(command):
                return fault
        return None

    def wait(self, seconds: float) -> bool:
        """Sleep that ends early when the simulator stops; ``False`` if it stopped."""
        return not self._stop.wait(seconds)

    # -- serving ---------------------------------------------------------------------------

    def _send(self, data: bytes) -> None:
        if self._master >= 0 and not self._stop.is_set():
            os.write(self._master, data)

    def _serve(self) -> None:
        buffer = ""
        try:
            while not self._stop.is_set():
                if self.unplugged:
                    self._close_master()
                    return
                ready, _, _ = select.select([self._master], [], [], 0.02)
                if not ready:
                    continue
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    return
                buffer += data.decode("ascii", errors="replace")
                commands, buffer = self.split(buffer)
                for command in commands:
                    if self.unplugged:
                        break
                    self._dispatch(command)
        except BaseException as e:  # surfaced to tests through .error
            self.error = e
            raise

    def _dispatch(self, command: str) -> None:
        self.received.append(command)
        fault = self.take_fault(REPLY_FAULTS, command.upper())
        if fault is not None and fault.kind == "vanish":
            self.unplug()
            return
        if self.echo:
            self._send((command + self.eol).encode("ascii", errors="replace"))
        reply = self.handle(command)
        if reply is None or self._stop.is_set():
            return
        data = (reply + self.eol).encode("ascii", errors="replace")
        if fault is None:
            self._send(data)
        elif fault.kind == "garble":
            self._send(garble(data))
        elif fault.kind == "corrupt":
            self._send(corrupt(data, fault.digit))
        elif fault.kind == "stall":
            if self.wait(fault.stall_s):
                self._send(data)
        # "drop": executed, never answered


def corrupt(data: bytes, digit: int = 1) -> bytes:
    """``data`` with its ``digit``-th decimal digit changed to ``(d + 5) mod 10``: still valid ASCII, still parses."""
    body = bytearray(data)
    positions = [i for i, b in enumerate(body) if 0x30 <= b <= 0x39]
    if positions:
        i = positions[min(digit, len(positions) - 1)]
        body[i] = 0x30 + (body[i] - 0x30 + 5) % 10
    return bytes(body)


def garble(data: bytes) -> bytes:
    """Line noise over ``data``: keeps the line end, replaces characters with non-ASCII/control bytes."""
    body = bytearray(data.rstrip(b"\r\n"))
    noise = b"\xff\x1b\xfe\x00"
    if not body:
        body = bytearray(b"\xff")
    for k, i in enumerate(range(0, len(body), 3)):
        body[i] = noise[k % len(noise)]
    return bytes(body) + b"\r\n"
