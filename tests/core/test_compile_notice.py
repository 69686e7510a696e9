"""A node's progress bar says when numba compiles a kernel (sbrdf_core.compile_notice)."""

from __future__ import annotations

import numpy as np
from numba import njit

from sbrdf_core import compile_notice
from sbrdf_core.runner import Runner


def _fresh_kernel():
    """A kernel numba has not compiled in this process (no cache=True: compiled on every first call)."""

    @njit
    def inner_helper(a):
        return a * 2.0

    @njit
    def outer_kernel(a):
        return inner_helper(a).sum()

    return outer_kernel


def test_one_note_per_outermost_compilation_then_cleared():
    notes: list[str | None] = []
    stop = compile_notice.watch(notes.append)
    try:
        assert _fresh_kernel()(np.ones(3)) == 6.0
    finally:
        stop()
    # The callee's compilation is part of the outer one: one note, then cleared.
    assert len(notes) == 2, notes
    assert "outer_kernel" in notes[0] and "numba compiling" in notes[0] and "test_compile_notice" in notes[0]
    assert notes[1] is None


def test_no_note_after_stop_and_only_the_newest_watcher_gets_it():
    older: list[str | None] = []
    newer: list[str | None] = []
    stop_older = compile_notice.watch(older.append)
    stop_newer = compile_notice.watch(newer.append)
    _fresh_kernel()(np.ones(2))
    stop_newer()
    assert older == [] and len(newer) == 2
    _fresh_kernel()(np.ones(2))
    stop_older()
    assert len(older) == 2
    before = (len(older), len(newer))
    _fresh_kernel()(np.ones(2))
    assert (len(older), len(newer)) == before


def test_a_cached_kernel_is_no_compilation():
    notes: list[str | None] = []
    kernel = _fresh_kernel()
    kernel(np.ones(2))  # compiled here, before watching
    stop = compile_notice.watch(notes.append)
    try:
        kernel(np.ones(5))  # the same signature: no compilation, no note
    finally:
        stop()
    assert notes == []


def test_the_runner_bar_shows_the_note(capsys):
    bar = Runner(progress=True)._bar("fit", 3, 0)
    try:
        _fresh_kernel()(np.ones(2))
        bar(3)
    finally:
        bar(None)
    err = capsys.readouterr().err
    assert "numba compiling test_compile_notice.outer_kernel: first run on this machine only" in err
    assert "3/3" in err


def test_a_failing_bar_does_not_fail_the_compilation():
    def broken(note):
        raise RuntimeError("the bar is gone")

    stop = compile_notice.watch(broken)
    try:
        assert _fresh_kernel()(np.ones(4)) == 8.0
    finally:
        stop()
