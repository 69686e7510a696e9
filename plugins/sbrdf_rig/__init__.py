"""Gonioreflectometer rig: serial motor drivers, their simulators, kinematics and pose planning.

Registers two ``device`` plugins (capture sources create them through
``Registry.create("device", name, params)``):

``ptu``
    :class:`sbrdf_rig.ptu.PanTiltUnit`, Directed Perception PTU command set.
``indexer``
    :class:`sbrdf_rig.indexer.Indexer`, Compumotor 6000-series command language.

and one ``capture`` source:

``gonio``
    :class:`sbrdf_rig.gonio.GonioCapture`: drives those motors and a camera
    device through a pose plan, writing an ``sbrdf-capture/1`` folder pose by
    pose (resumable), and hands the poses to the Capture node.

Each contribution's parameters are declared in :mod:`.declarations`, which
imports neither pyserial nor NumPy; this manifest hands them to the registry
and the implementations take the same tuples as their ``params``.  The simulators
(:mod:`sbrdf_rig.sim`) and the pose planner (:mod:`sbrdf_rig.planning`) are
this package's own; what other packages share with it (the serial link,
motor-controller base and pty simulator base, the rig kinematics, the capture
folder) is in :mod:`sbrdf_lib.serial`, :mod:`sbrdf_lib.rig_geometry` and
:mod:`sbrdf_lib.capture_folder`.  See ``docs/acquisition-rig.md``.  This module
imports nothing heavy.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_devices():
    return [
        PluginSpec("ptu", "sbrdf_rig.ptu:PanTiltUnit", params=declarations.PTU,
                   summary="Pan-tilt unit over serial, Directed Perception PTU command set (PP/TP, A, H)"),
        PluginSpec("indexer", "sbrdf_rig.indexer:Indexer", params=declarations.INDEXER,
                   summary="Rotary indexer over serial, Compumotor 6000-series language (D, GO, TPE, LS)"),
    ]


@hookimpl
def sbrdf_captures():
    return [
        PluginSpec("gonio", "sbrdf_rig.gonio:GonioCapture", params=declarations.GONIO,
                   summary="Drive the gonioreflectometer (motors + camera) through a pose plan into an "
                           "sbrdf-capture/1 folder, resumably"),
    ]
