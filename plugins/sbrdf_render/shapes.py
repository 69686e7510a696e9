"""Moved to :mod:`sbrdf_lib.surface` (shapes, frames, ray hits) and :mod:`sbrdf_lib.mesh` (OBJ); kept for one release."""

from sbrdf_lib.mesh import load_obj
from sbrdf_lib.surface import EPS, Hits, Mesh, intersect, intersect_mesh, local_frame, tessellate, vertex_frames

__all__ = ["EPS", "Hits", "Mesh", "intersect", "intersect_mesh", "load_obj", "local_frame", "tessellate",
           "vertex_frames"]
