"""Walkthroughs of static scenes (seed 004 §4.6.4): the ``Walkthrough`` node.

Why a package of its own: a walkthrough is a sequence product (frames, a
video, per-frame timings), not one image, and it orders itself after the
light-map bake it depends on (``in: {lightmaps: bake}``).  The drawing is the
``gl`` renderer's (:mod:`sbrdf_render.walkthrough`, reached through the
registry); the camera path is :mod:`sbrdf_lib.camera_path`.  See
``docs/walkthrough.md``.
"""

from sbrdf_core.plugin import hookimpl


@hookimpl
def sbrdf_node_kinds():
    from .node import Walkthrough

    return [Walkthrough]


@hookimpl
def sbrdf_artifact_kinds():
    from .node import WALKTHROUGH

    return [WALKTHROUGH]
