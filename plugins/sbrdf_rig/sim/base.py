"""Moved to :mod:`sbrdf_lib.serial.sim`; this re-export keeps old imports working for one release."""

from sbrdf_lib.serial.sim import FAULT_KINDS, REPLY_FAULTS, Fault, PtySimulator, SimulatedAxis, corrupt, garble

__all__ = ["FAULT_KINDS", "REPLY_FAULTS", "Fault", "PtySimulator", "SimulatedAxis", "corrupt", "garble"]
