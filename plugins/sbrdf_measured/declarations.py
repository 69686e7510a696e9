"""The measured-BRDF plugin's declarations, read without importing the readers or the model.

``sbrdf plugins``, graph validation and the reference docs read the ``merl``
model's parameters through its :class:`~sbrdf_core.plugin.PluginSpec`
(``__init__.py``); :class:`.model.MerlModel`, imported when a graph evaluates
it, takes the same tuple as its ``params``.  The node kinds (:mod:`.nodes`)
declare their defaults from :data:`MERL_DIMS` here and import the file
readers when they run.  This module imports only :mod:`sbrdf_core.params`.
"""

from __future__ import annotations

from sbrdf_core.params import Param

#: The MERL database's table dimensions (θh, θd, φd).
MERL_DIMS = (90, 90, 180)

MERL = (
    Param("path", "str", None, "MERL .binary file (relative to the graph file; null: no table, f_r = scale/pi)",
          nullable=True, extra={"path": True}),
    Param("interpolation", "str", "trilinear", "table lookup: trilinear between the bins' start nodes, or "
          "nearest (MERL's BRDFRead.cpp lookup)", choices=("trilinear", "nearest")),
)
