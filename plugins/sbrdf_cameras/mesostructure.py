"""Moved to :mod:`sbrdf_lib.mesostructure`; this re-export keeps old imports working for one release."""

from sbrdf_lib.mesostructure import KEYS, MAX_STEPS, PROCEDURAL, Mesostructure, normals, procedural

__all__ = ["KEYS", "MAX_STEPS", "PROCEDURAL", "Mesostructure", "normals", "procedural"]
