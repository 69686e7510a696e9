"""When a NumPy pass has a compiled (numba) twin, which one runs: decided by the size of the work.

The twins give the same values (bit for bit, or to an ulp where so stated),
so the choice is about cost only.  The first compiled call in a process loads
numba and the kernel's cached machine code, a one-off that a small pass never
repays; from :data:`MIN_ELEMENTS` on (a Fit tile is a few hundred thousand
samples) the compiled pass is taken.  The rule reads only the size of the
arrays: what else the process happens to have imported does not change
which code runs.
"""

from __future__ import annotations

#: Elements (samples × channels, or texels × poses) from which the compiled pass runs.
MIN_ELEMENTS = 1 << 16


def worth_compiling(elements: int) -> bool:
    """Whether a pass over ``elements`` array elements takes its compiled twin."""
    return elements >= MIN_ELEMENTS
