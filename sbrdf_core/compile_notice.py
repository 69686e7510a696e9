"""Say on a node's progress bar when numba is compiling a kernel, and for how long it did.

The first run on a machine compiles the fitting kernels (numba's ``cache=True``
keeps them for later runs): tens of seconds a model on 2 cores, while
the Fit node's bar sits at 0 % and then, after its first chunk, shows an
estimate of an hour.  numba announces each compilation that is not a cache hit
(the ``numba:compile`` event), so the bar can say what it waits for::

    fit         :   0%|          | 0/72 [00:20<?, ?chunk/s, numba compiling the fitting engine (solve) for a model: first run on this machine only]

:func:`watch` routes those events to the bar shown now; a compilation inside
another (a kernel's callees) is part of the outer one.  Runs on a
``distributed`` cluster compile in the workers, whose events stay there.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

logger = logging.getLogger(__name__)

_LOCK = threading.Lock()
_shows: list[Callable[[str | None], None]] = []  # the bars shown now; the newest gets the note
_listener = None


def _note(name: str) -> str:
    return f"numba compiling {name}: first run on this machine only"


def _kernel_name(dispatcher) -> str:
    """``geometry_compiled.kernel``: the module's last part and the function's name; for the fitting
    engine's loops (``sbrdf_core.engine``), which loop and the model whose kernel it is compiled around."""
    func = getattr(dispatcher, "py_func", None)
    if func is None:
        return "a kernel"
    module = getattr(func, "__module__", "")
    if module.startswith("sbrdf_kernels."):  # lm_<kernel module with _>_<kernel name>_<digest>
        return f"the fitting engine ({func.__name__}) for {module.partition('.lm_')[2].rsplit('_', 1)[0]}"
    return f"{getattr(func, '__module__', '').rpartition('.')[2]}.{func.__name__}".lstrip(".")


def _make_listener():
    from numba.core import event

    class Listener(event.Listener):
        """Outermost ``numba:compile`` events -> the newest bar's note (numba compiles under one global lock)."""

        depth = 0
        name = ""
        t0 = 0.0

        def on_start(self, ev):
            self.depth += 1
            if self.depth == 1:
                self.name = _kernel_name(ev.data.get("dispatcher"))
                self.t0 = time.perf_counter()
                _show(_note(self.name))

        def on_end(self, ev):
            self.depth -= 1
            if self.depth == 0:
                _show(None)
                logger.info("compiled %s (numba) in %.1f s; cached for later runs", self.name,
                            time.perf_counter() - self.t0)

    listener = Listener()
    event.register("numba:compile", listener)
    return listener


def _show(message: str | None) -> None:
    with _LOCK:
        show = _shows[-1] if _shows else None
    if show is not None:
        try:
            show(message)
        except Exception:  # a note must never fail the compilation it is about (numba calls this inside it)
            logger.debug("compile note not shown", exc_info=True)


def watch(show: Callable[[str | None], None]) -> Callable[[], None]:
    """From now on, numba compilations in this process call ``show(note)`` as they start and ``show(None)`` as
    they end (the newest watcher only); returns the function that stops it.  Nothing where numba is missing."""
    global _listener
    with _LOCK:
        if _listener is None:
            try:
                _listener = _make_listener()
            except ImportError:  # pragma: no cover (numba is a dependency)
                _listener = False
        _shows.append(show)

    def stop() -> None:
        with _LOCK:
            if show in _shows:
                _shows.remove(show)

    return stop
