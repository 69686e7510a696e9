"""What a capture source that writes a capture folder and reads it back through the ``folder`` plugin shares.

The gonio and virtual-folder sources take their photographs into a folder and
return poses as the ``folder`` plugin reads them, so the Capture node's
calibration and the read report are the reader's.  ``bind`` (the source's own)
creates ``self.reader`` from the registry.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np

if TYPE_CHECKING:
    from .folder import FolderCapture


class ReadBack:
    """Mixin of a capture source whose poses are read back through its ``folder`` reader (``self.reader``)."""

    #: The source's registered name, for the messages.
    source: ClassVar[str]
    reader: FolderCapture | None

    def bind(self, registry) -> None:  # pragma: no cover (every source defines it)
        raise NotImplementedError

    def calibrate(self, *, dark_offset: np.ndarray | None = None, dark_rate: np.ndarray | None = None,
                  flat: np.ndarray | None = None) -> None:
        """Dark model and flat field of the Capture node's ``dark``/``flat`` inputs: the folder reader applies them
        (:meth:`sbrdf_capture.folder.FolderCapture.calibrate`)."""
        if self.reader is None:
            from sbrdf_core.registry import default_registry

            self.bind(default_registry())
        self._folder_reader().calibrate(dark_offset=dark_offset, dark_rate=dark_rate, flat=flat)

    def read_report(self) -> tuple[str, dict] | None:
        """What reading the folder back found (the folder plugin's :meth:`~sbrdf_capture.folder.FolderCapture.read_report`)."""
        return self.reader.read_report() if self.reader is not None else None

    def _folder_reader(self) -> FolderCapture:
        """The ``folder`` reader the poses are read back through; :meth:`bind` creates it."""
        assert self.reader is not None, f"{self.source}: the folder reader is used before bind()"
        return self.reader
