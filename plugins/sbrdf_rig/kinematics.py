"""Moved to :mod:`sbrdf_lib.rig_geometry`; this re-export keeps old imports working for one release."""

from sbrdf_lib.rig_geometry import MOTORS, InverseSolution, RigGeometry, RigPoses, forward, inverse

__all__ = ["MOTORS", "InverseSolution", "RigGeometry", "RigPoses", "forward", "inverse"]
