"""Moved to :mod:`sbrdf_lib.serial.controller`; this re-export keeps old imports working for one release."""

from sbrdf_lib.serial.controller import MotorController

__all__ = ["MotorController"]
