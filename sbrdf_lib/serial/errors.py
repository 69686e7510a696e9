"""Errors a serial device driver can raise, each naming the port, the command and what came back.

A capture that runs for hours stops on the first of these, so the message has
to say enough to act on without a debugger: which device on which port, the
exact command sent, and the exact bytes received (or that nothing came).
Every class derives from :class:`sbrdf_core.errors.SbrdfError`, so the runner
reports them like any other deliberate sbrdf error.
"""

from __future__ import annotations

from sbrdf_core.errors import SbrdfError

__all__ = ["DeviceClosed", "DeviceError", "DeviceRefused", "GarbledReply", "ImplausibleReply", "LinkLost",
           "PositionError", "ReplyTimeout", "SoftLimitError"]


class DeviceError(SbrdfError):
    """A motor controller failed; ``port``, ``command`` and ``received`` say where and how.

    ``received`` is the raw reply (``None`` when nothing came back).
    """

    def __init__(self, message: str, *, device: str = "", port: str = "", command: str | None = None,
                 received: bytes | str | None = None):
        self.device = device
        self.port = port
        self.command = command
        self.received = received
        where = f"{device} on {port}" if device and port else (device or port or "device")
        detail = []
        if command is not None:
            detail.append(f"command {command!r}")
        if command is not None or received is not None:
            detail.append("received nothing" if received is None else f"received {received!r}")
        suffix = f" ({', '.join(detail)})" if detail else ""
        super().__init__(f"{where}: {message}{suffix}")


class ReplyTimeout(DeviceError):
    """No complete reply arrived within the timeout (dropped reply or a stalled controller)."""


class GarbledReply(DeviceError):
    """A reply arrived but is not what the protocol allows for that command."""


class DeviceRefused(DeviceError):
    """The controller understood the command and answered with an error (``!`` or ``?``)."""


class SoftLimitError(DeviceError):
    """A move was refused before anything was sent: the target lies outside the soft limits."""


class PositionError(DeviceError):
    """After a move the read-back position differs from the target by more than the tolerance."""


class DeviceClosed(DeviceError):
    """The driver was closed (by :meth:`close` or after a fatal error) and cannot be used."""


class LinkLost(DeviceError):
    """The serial link failed at the operating-system level: the device vanished (unplugged, powered off).

    Raised for ``OSError``, ``termios.error`` and ``serial.SerialException``
    from the port (anything but a timeout).  Never retried: the command
    cannot be sent again on a port that is gone.  ``reason`` is the OS error in
    one line (``write failed: termios.error: [Errno 5] Input/output error``).
    """

    reason: str = ""


class ImplausibleReply(GarbledReply):
    """A well-formed reply whose value cannot be right: it changes between repeated queries of a
    constant, lies outside what the controller model allows, or disagrees with the value just set.

    Line noise that turns one digit into another stays valid ASCII and parses;
    this is how the drivers catch it (``readings`` lists every value read).
    """

    def __init__(self, message: str, *, readings=(), **kwargs):
        self.readings = list(readings)
        super().__init__(message, **kwargs)
