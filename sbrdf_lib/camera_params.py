"""The settings every frame-camera driver declares, read without importing the drivers.

Drivers declare their parameters in modules that listing and validation read
without importing a camera SDK or :mod:`sbrdf_lib.camera`'s frame handling;
this module imports only :mod:`sbrdf_core.params`, and :mod:`sbrdf_lib.camera`
reads the same tuple.
"""

from __future__ import annotations

from sbrdf_core.params import Param

__all__ = ["COMMON_PARAMS"]

#: Settings every frame-camera driver declares (each driver adds its own after these).
COMMON_PARAMS = (
    Param("serial", "str", None, "serial number of the camera to open; default the first one found", nullable=True),
    Param("pixel_format", "str", None, "sensor pixel format (Mono8, Mono12, RGB8, ...); default the camera's own",
          nullable=True),
    Param("gain_db", "float", 0.0, "analogue gain (auto gain is switched off)", bounds=(0.0, None), unit="dB"),
    Param("black_level", "float", None, "black level (pedestal) in camera units; default the camera's own",
          nullable=True),
    Param("trigger", "str", "software", "software: the capture triggers each frame; hardware: the camera waits "
          "for a pulse on its trigger line (from the motion controller)", choices=("software", "hardware")),
    Param("timeout_s", "float", 5.0, "frame timeout after the trigger, on top of the exposure time",
          bounds=(1e-3, 3600.0), unit="s"),
    Param("nominal_exposure_s", "float", None, "for a camera without exposure control: the exposure it has; only "
          "this time is then accepted", nullable=True, bounds=(1e-9, None), unit="s"),
)
