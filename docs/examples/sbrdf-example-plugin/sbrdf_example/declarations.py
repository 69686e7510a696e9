"""The example's parameters, declared once and read without importing the driver or the effect.

``sbrdf plugins``, graph validation and the reference docs read these through
the :class:`~sbrdf_core.plugin.PluginSpec` of each contribution
(``__init__.py``); :class:`.turntable.Turntable` and
:class:`.ambient.AmbientEffect`, imported when a graph uses them, take the
same tuples as their ``params``.  This module imports only
:mod:`sbrdf_core.params` (no pyserial, no NumPy).
"""

from __future__ import annotations

from sbrdf_core.params import REQUIRED, Param

TURNTABLE = (
    Param("port", "str", REQUIRED, "serial device path (/dev/ttyUSB0, a simulator's pty); `sim` in a gonio graph"),
    Param("baudrate", "int", 19200, "line speed", choices=(9600, 19200, 38400, 115200)),
    Param("timeout_s", "float", 1.0, "how long to wait for a complete reply", bounds=(0.001, 60.0), unit="s"),
    Param("retries", "int", 3, "extra attempts after a dropped/garbled reply or a missed position", bounds=(0, 20)),
    Param("tolerance_deg", "float", 0.01, "largest accepted difference between target and read-back angle",
          bounds=(0.0, 10.0), unit="deg"),
    Param("limits_deg", "list", [-180.0, 180.0], "soft limits [low, high]; moves outside are refused unsent",
          length=2, item="float", bounds=(-720.0, 720.0), unit="deg"),
    Param("move_timeout_s", "float", 60.0, "longest a single move may take", bounds=(0.01, 3600.0), unit="s"),
    Param("poll_s", "float", 0.005, "status polling interval while the stage moves", bounds=(0.0, 1.0), unit="s"),
)

AMBIENT = (
    Param("radiance", "list", [0.1, 0.1, 0.1], "sky radiance (RGB) arriving from every direction above the surface",
          length=3, item="float", bounds=(0.0, None)),
)
