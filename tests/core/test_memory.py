"""sbrdf_core._runtime: the malloc arena cap the runner applies before running threads."""

import os
import platform
import subprocess
import sys

import pytest

glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt(M_ARENA_MAX) is glibc's")

CODE = "from sbrdf_core._runtime import limit_arenas; print(limit_arenas())"


def _run(env: dict) -> str:
    return subprocess.run([sys.executable, "-c", CODE], env=env, capture_output=True, text=True, check=True).stdout.strip()


@glibc
def test_limit_arenas_applies_on_glibc():
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}
    assert _run(env) == "True"


def test_limit_arenas_leaves_a_users_setting_alone():
    assert _run({**os.environ, "MALLOC_ARENA_MAX": "4"}) == "False"


#: mallinfo2 and raw malloc/free through ctypes, after limit_arenas.
MALLOC = """
import ctypes
from sbrdf_core._runtime import limit_arenas

class MI(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost".split()]

libc = ctypes.CDLL(None)
libc.mallinfo2.restype = MI
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, (ctypes.c_size_t,)
libc.free.argtypes = (ctypes.c_void_p,)
limit_arenas()
"""

MMAP_CODE = MALLOC + """libc.free(libc.malloc(24 << 20))  # a pose block's temporary, mapped then freed
before = libc.mallinfo2().hblkhd
p = libc.malloc(8 << 20)  # a texel tile
print(libc.mallinfo2().hblkhd - before >= 8 << 20)
libc.free(p)
"""


@glibc
def test_block_sized_temporaries_stay_mapped_after_a_larger_one_was_freed():
    """glibc raises its mmap threshold to the largest mapped block freed (up to 32 MiB):
    every smaller block-sized temporary then came from the arenas, whose freed memory
    grew with the number of pose blocks (Register + Reflectance peak 413 MB at 8 GB
    against 330 at 2 GB).  limit_arenas fixes the threshold, so an 8 MiB tile after a
    freed 24 MiB block is still mapped, and returned to the system when freed."""
    env = {k: v for k, v in os.environ.items() if k not in ("MALLOC_ARENA_MAX", "MALLOC_MMAP_THRESHOLD_")}
    out = subprocess.run([sys.executable, "-c", MMAP_CODE], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"


TRIM_CODE = MALLOC + """from sbrdf_core._runtime import TRIM_THRESHOLD
ps = [libc.malloc(1 << 20) for _ in range(3)]  # a pose's temporaries: in the heap, below the mmap threshold
for p in reversed(ps):
    libc.free(p)
print(libc.mallinfo2().keepcost >= 3 << 20, libc.mallinfo2().keepcost <= TRIM_THRESHOLD + (1 << 20))
"""


@glibc
def test_a_poses_temporaries_stay_in_the_heap_when_freed():
    """glibc trims a heap's free top above 128 KiB by default, so every pose faulted its few MB of temporaries
    in again (a million minor faults in a 2 GB Register).  limit_arenas keeps up to TRIM_THRESHOLD free at the
    top (mallinfo2's keepcost), and no more."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", TRIM_CODE], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "True"]
