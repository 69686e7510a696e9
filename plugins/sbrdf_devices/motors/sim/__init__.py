"""Simulated motor controllers serving the real protocols on a pseudo-terminal.

Tests and the virtual rig open the simulator's slave device with pyserial,
exactly as they would open ``/dev/ttyUSB0``, so the drivers under test are the
production drivers, byte for byte.  Faults (dropped, garbled or late replies,
a motor that misses its target) are injected per simulator with
:class:`Fault`::

    with SimulatedPTU(faults=[Fault("drop", match="PP", times=1)]) as sim:
        with PanTiltUnit(port=sim.port, timeout_s=0.2) as ptu:
            ptu.move_to(pan_deg=10.0)
"""

from sbrdf_lib.serial.sim import Fault, PtySimulator, SimulatedAxis

from .indexer import SimulatedIndexer
from .ptu import SimulatedPTU

__all__ = ["Fault", "PtySimulator", "SimulatedAxis", "SimulatedIndexer", "SimulatedPTU"]
