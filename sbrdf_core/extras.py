"""Optional dependencies: import one, or say which extra installs it.

Heavy third-party packages (OpenGL, serial ports, plotting, a cluster) are
extras of the ``sbrdf`` distribution (pyproject ``[project.optional-dependencies]``),
so a plain install stays small.  Code that needs one imports it through
:func:`require`, which turns the bare ``ImportError`` into a
:class:`MissingExtra` naming the extra to install.  ``MissingExtra`` is a
:class:`~sbrdf_core.errors.PluginError` (the registry's failure isolation and the
CLI report it as one line) and an ``ImportError`` (``except ImportError`` keeps
working)::

    from sbrdf_core.extras import require

    moderngl = require("moderngl", extra="gl", feature="the gl renderer")
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import PluginError

__all__ = ["EXTRAS", "MissingExtra", "require"]

#: Module -> (extra, distribution) for the optional dependencies pyproject declares.
EXTRAS = {
    "moderngl": ("gl", "moderngl"),
    "serial": ("rig", "pyserial"),
    "matplotlib": ("plot", "matplotlib"),
    "distributed": ("distributed", "distributed"),
    "trimesh": ("mesh", "trimesh"),
    "MaterialX": ("interchange", "materialx"),
    "pxr": ("interchange", "usd-core"),
    "mitsuba": ("interchange", "mitsuba"),
    "selenium": ("interchange", "selenium"),
}


class MissingExtra(PluginError, ImportError):
    """An optional dependency is not installed; the message names the extra that installs it."""

    def __init__(self, module: str, extra: str, feature: str = ""):
        self.module, self.extra = module, extra
        super().__init__(f"{feature or 'this part of sbrdf'} needs the optional dependency {module!r}, which is not "
                         f"installed: pip install 'sbrdf[{extra}]'")
        self.name = module


def require(module: str, extra: str | None = None, feature: str = "") -> ModuleType:
    """Import ``module``, or raise :class:`MissingExtra` saying ``pip install 'sbrdf[extra]'``.

    ``extra`` defaults to the one :data:`EXTRAS` lists for the module's top-level
    package; ``feature`` names what needs it (``"the gl renderer"``).
    """
    try:
        return importlib.import_module(module)
    except ImportError as e:
        top = module.partition(".")[0]
        if getattr(e, "name", None) not in (None, module, top):  # the module is there, but it failed to import
            raise
        raise MissingExtra(module, extra or EXTRAS.get(top, (top, top))[0], feature) from e
