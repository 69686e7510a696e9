"""Serial device drivers' shared layer: a line-oriented link, a motor-controller base, errors, a pty simulator.

What every driver of a checksumless ASCII serial controller needs, so a
third-party device plugin (``docs/examples/sbrdf-example-plugin``) writes only
its protocol: :class:`SerialLink` (deadlines, bounded retries,
resynchronisation; :mod:`.link`), :class:`MotorController` (soft limits,
verified moves, clean stops; :mod:`.controller`), the :class:`DeviceError`
family (:mod:`.errors`) and :class:`PtySimulator` (a controller on a
pseudo-terminal with fault injection, for tests without hardware; :mod:`.sim`).
Needs pyserial (the ``[rig]`` extra).
"""

from .controller import LINK_PARAMS, MotorController
from .errors import (
                     DeviceClosed,
                     DeviceError,
                     DeviceRefused,
                     GarbledReply,
                     ImplausibleReply,
                     LinkLost,
                     PositionError,
                     ReplyTimeout,
                     SoftLimitError,
)
from .link import OS_LINK_ERRORS, SerialLink, os_reason
from .sim import FAULT_KINDS, REPLY_FAULTS, Fault, PtySimulator, SimulatedAxis, corrupt, garble

__all__ = ["LINK_PARAMS", "FAULT_KINDS", "OS_LINK_ERRORS", "REPLY_FAULTS", "DeviceClosed", "DeviceError", "DeviceRefused", "Fault",
           "GarbledReply", "ImplausibleReply", "LinkLost", "MotorController", "PositionError", "PtySimulator",
           "ReplyTimeout", "SerialLink", "SimulatedAxis", "SoftLimitError", "corrupt", "garble", "os_reason"]
