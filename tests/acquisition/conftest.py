"""Fixtures shared by the acquisition tests (drivers, the gonio capture source)."""

from __future__ import annotations

import pytest


@pytest.fixture
def start_simulator():
    """Start simulators for a test: ``sim = start_simulator(SimulatedPTU, faults=[...])``; all stop at teardown."""
    started = []

    def start(cls, **kwargs):
        sim = cls(**kwargs).start()
        started.append(sim)
        return sim

    yield start
    for sim in started:
        sim.stop()
        assert sim.error is None, f"simulator thread failed: {sim.error!r}"
