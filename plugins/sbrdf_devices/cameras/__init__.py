"""Camera devices: the simulated ``virtual-camera`` (:mod:`.virtual`) and the frame cameras ``pylon``,
``aravis``, ``genicam``, ``uvc`` and ``gphoto`` (one module each, on :mod:`sbrdf_lib.camera`'s base)."""
