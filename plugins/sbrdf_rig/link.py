"""Moved to :mod:`sbrdf_lib.serial.link`; this re-export keeps old imports working for one release."""

from sbrdf_lib.serial.link import OS_LINK_ERRORS, SerialLink, _head, os_reason

__all__ = ["OS_LINK_ERRORS", "SerialLink", "_head", "os_reason"]
