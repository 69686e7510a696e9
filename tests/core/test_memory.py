"""sbrdf_core.memory: the malloc arena cap the runner applies before running threads."""

import os
import platform
import subprocess
import sys

import pytest

glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt(M_ARENA_MAX) is glibc's")

CODE = "from sbrdf_core.memory import limit_arenas; print(limit_arenas())"


def _run(env: dict) -> str:
    return subprocess.run([sys.executable, "-c", CODE], env=env, capture_output=True, text=True, check=True).stdout.strip()


@glibc
def test_limit_arenas_applies_on_glibc():
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}
    assert _run(env) == "True"


def test_limit_arenas_leaves_a_users_setting_alone():
    assert _run({**os.environ, "MALLOC_ARENA_MAX": "4"}) == "False"

