"""Capture: photographs of the sample under many light and view directions.

The node's plugin is a *capture source* (a device rig, a capture folder, a
simulator).  The source describes the poses up front and hands over one linear
HDR image per pose; the node stores them pose-major, one pose per chunk, so an
interrupted capture resumes from the last pose written.

Calibration captures are nodes too: a ``DarkFrame`` artifact wired into the
optional ``dark`` input and a ``FlatField`` into ``flat`` are handed to the
source's ``calibrate`` (dark offset and rate, normalised flat, each
``(H, W, 3)``) before it describes the poses, and the source corrects every
exposure with them before merging the bracket.  A source without
``calibrate`` refuses the inputs.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..artifacts import CaptureSet
from ..contracts import CaptureSource, optional
from ..errors import SbrdfError
from ..types import CaptureDescription
from .base import BuildContext, NodeKind, Output, Port, shared

#: The node's summary of what reading found; ``sbrdf run -q`` silences it (``sbrdf_core.cli.REPORT_LOGGER``).
report_logger = logging.getLogger("sbrdf.report.capture")


def _read_block(index: np.ndarray, source) -> np.ndarray:
    """Kernel: one pose -> ``(1, H, W, 4)`` = RGB radiance + validity."""
    image, valid = source.read_pose(int(index[0]))
    image = np.asarray(image, dtype=np.float32)
    finite = np.isfinite(image).all(axis=-1)
    out = np.empty(image.shape[:2] + (4,), np.float32)
    out[..., :3] = np.where(finite[..., None], image, 0.0)
    out[..., 3] = np.asarray(valid, bool) & finite
    return out[None]


class Capture(NodeKind):
    name = "Capture"
    doc = "Photograph the sample from a capture source; stores a pose-major CaptureSet."
    output = CaptureSet
    plugin_category = "capture"
    inputs = (
        Port("dark", ("DarkFrame",), "dark model (offset + rate · t) subtracted from every exposure", optional=True),
        Port("flat", ("FlatField",), "normalised flat field every exposure is divided by", optional=True),
    )

    @classmethod
    def prepare(cls, ctx: BuildContext) -> dict[str, Any]:
        """The calibration arrays of the ``dark`` and ``flat`` inputs (small: one frame each)."""
        wanted: dict[str, Any] = {}
        if "dark" in ctx.inputs:
            wanted.update(dark_offset=ctx.inputs["dark"].array("offset"), dark_rate=ctx.inputs["dark"].array("rate"))
        if "flat" in ctx.inputs:
            wanted["flat"] = ctx.inputs["flat"].array("flat")
        return wanted

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        source: CaptureSource = ctx.plugin
        if ctx.prepared:
            calibrate = optional(source, "calibrate", "capture")
            if calibrate is None:
                raise SbrdfError(f"node {ctx.node!r}: capture plugin {ctx.plugin_name!r} cannot apply calibration "
                                 f"captures ({', '.join(sorted(ctx.inputs))} inputs); folder, virtual-folder and "
                                 "gonio can")
            calibrate(**ctx.prepared)
        desc: CaptureDescription = source.describe()
        P, H, W = desc.n_poses, desc.height, desc.width
        index = da.arange(P, chunks=1)
        # The source holds the whole manifest (O(poses)); as one graph key it reaches a
        # worker once, where a plain argument is copied into every pose's task (O(poses²)).
        packed = da.map_blocks(
            _read_block, index, shared(source),
            new_axis=[1, 2, 3], chunks=((1,) * P, (H,), (W,), (4,)), dtype=np.float32,
            name=ctx.key("capture-read"),
        )
        small = lambda a: da.from_array(np.asarray(a, dtype=np.float64))  # noqa: E731
        return Output(
            arrays={
                "images": packed[..., :3],
                "valid": packed[..., 3] > 0.5,
                "light_pos": small(desc.light_pos),
                "camera_R": small(desc.camera_R),
                "camera_t": small(desc.camera_t),
                "exposure_s": small(desc.exposure_s),
            },
            attrs=desc.attrs(),
            finalize=lambda artifact: _report(ctx.node, source),
            sequential=bool(optional(source, "sequential", "capture")),
        )


def _report(node: str, source) -> dict[str, Any]:
    """The source's ``read_report`` as one warning for the node, and its attributes for the CaptureSet.

    Poses read in other processes (a dask cluster's workers) are not in it:
    their sources log per pose at debug level there.
    """
    read_report = optional(source, "read_report", "capture")
    report = read_report() if read_report is not None else None
    if not report:
        return {}
    line, attrs = report
    report_logger.warning("capture node %r: %s", node, line)
    return dict(attrs or {})
