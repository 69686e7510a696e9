"""The parameters every serial motor-controller driver declares, read without importing the drivers.

Drivers declare their parameters in modules that listing and validation read
without importing pyserial or the link (``sbrdf plugins`` opens no port); this
module imports only :mod:`sbrdf_core.params`, and
:mod:`sbrdf_lib.serial.controller` reads the same tuple.
"""

from __future__ import annotations

from sbrdf_core.params import REQUIRED, Param

__all__ = ["LINK_PARAMS"]

#: Parameters every serial motor controller takes (its link and its verified moves); a driver declares
#: ``params = (*LINK_PARAMS, <its own>)`` and passes them on to :class:`~sbrdf_lib.serial.SerialLink` and
#: :class:`~sbrdf_lib.serial.MotorController`.
LINK_PARAMS = (
    Param("port", "str", REQUIRED, "serial device path, e.g. /dev/ttyUSB0 or a simulator's pty"),
    Param("baudrate", "int", 9600, "line speed", choices=(1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)),
    Param("timeout_s", "float", 1.0, "how long to wait for a complete reply", bounds=(0.001, 60.0), unit="s"),
    Param("retries", "int", 3, "extra attempts after a dropped/garbled reply or a missed position", bounds=(0, 20)),
    Param("tolerance_deg", "float", 0.05, "largest accepted difference between target and read-back position",
          bounds=(0.0, 10.0), unit="deg"),
    Param("move_timeout_s", "float", 60.0, "longest a single move may take", bounds=(0.01, 3600.0), unit="s"),
)
