"""Light maps for walkthroughs (seed 004 §4.3, Eq 4.1): the ``LightmapBake`` node.

Why a package of its own: baking is an offline step of its own (Mühlbacher
took his maps from a photon mapper), reads the scene through the ``cpu``
renderer (reached through the registry) and writes what every renderer then
reads; the renderers' side (ρ_d·E from the maps) is in ``sbrdf_render``,
the maps' chart and file layout in :mod:`sbrdf_lib.lightmap`.
See ``docs/walkthrough.md``.
"""

from sbrdf_core.plugin import hookimpl


@hookimpl
def sbrdf_node_kinds():
    from .node import LightmapBake

    return [LightmapBake]


@hookimpl
def sbrdf_artifact_kinds():
    from .node import LIGHT_MAPS

    return [LIGHT_MAPS]
