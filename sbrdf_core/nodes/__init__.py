"""The node kinds of the pipeline, registered as the essential plugin.

Capture -> Register -> Reflectance -> Fit -> Quantize -> Render, and Export.  Each module
defines one node kind and the protocol its plugins implement.
"""

from __future__ import annotations

from ..plugin import hookimpl


@hookimpl
def sbrdf_node_kinds():
    from .capture import Capture
    from .export import Export
    from .fit import Fit
    from .quantize import Quantize
    from .reflectance import Reflectance
    from .register import Register
    from .render import Render

    return [Capture, Register, Reflectance, Fit, Quantize, Render, Export]
