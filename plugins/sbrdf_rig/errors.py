"""Moved to :mod:`sbrdf_lib.serial.errors`; this re-export keeps old imports working for one release."""

from sbrdf_lib.serial.errors import (
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

__all__ = ["DeviceClosed", "DeviceError", "DeviceRefused", "GarbledReply", "ImplausibleReply", "LinkLost",
           "PositionError", "ReplyTimeout", "SoftLimitError"]
