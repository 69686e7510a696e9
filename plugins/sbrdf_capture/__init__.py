"""Capture: the Capture node's sources and the calibration captures.

Sources (``capture`` plugins):

``folder`` (:mod:`.folder`)
    reads an ``sbrdf-capture/1`` folder: validated, HDR-merged (:mod:`.hdr`),
    linearised through a recorded or recovered response (:mod:`.response`),
    optionally colour-calibrated (:mod:`.colour`);
``synthetic`` (:mod:`.synthetic`)
    a texel-aligned simulation of a procedural material of any BRDF model;
``gonio`` (:mod:`.gonio`)
    drives the gonioreflectometer (motor and camera devices) through a pose
    plan (:mod:`.planning`) into a capture folder, resumably, and reads it back;
``virtual-folder`` (:mod:`.virtual_folder`)
    photographs a camera device (the virtual camera) into a capture folder
    (:mod:`.photograph`) and reads it back: a graph that makes its own
    simulated scan.

Calibration captures (node kinds, :mod:`.calibration`): ``DarkFrame`` and
``FlatField``, whose artifacts the Capture node's ``dark`` and ``flat``
inputs take.

The devices the sources and calibration nodes drive are another package's
(``sbrdf_devices``): they are named by plugin name and created through the
registry, never imported.  Each source's parameters are declared in
:mod:`.declarations`, which imports no source.  The capture-folder format
itself is in the library layer (:mod:`sbrdf_lib.capture_folder`, with the
response-curve tables in :mod:`sbrdf_lib.response` and the rig kinematics in
:mod:`sbrdf_lib.rig_geometry`), so what any writer writes ``folder`` reads.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_captures():
    return [
        PluginSpec(
            "folder",
            "sbrdf_capture.folder:FolderCapture",
            params=declarations.FOLDER,
            summary="Read an sbrdf-capture/1 folder (EXR, 8/16-bit PNG/TIFF): validated, HDR-merged, one pose at a time",
        ),
        PluginSpec(
            "synthetic",
            "sbrdf_capture.synthetic:SyntheticCapture",
            params=declarations.SYNTHETIC,
            summary="Simulated texel-aligned capture of a procedural material of any BRDF model",
        ),
        PluginSpec("gonio", "sbrdf_capture.gonio:GonioCapture", params=declarations.GONIO,
                   summary="Drive the gonioreflectometer (motors + camera) through a pose plan into an "
                           "sbrdf-capture/1 folder, resumably"),
        PluginSpec(
            "virtual-folder",
            "sbrdf_capture.virtual_folder:VirtualFolderCapture",
            params=declarations.VIRTUAL_FOLDER,
            summary="Photograph a camera device (the virtual camera) into an sbrdf-capture/1 folder, then read it as "
                    "folder does: a graph that makes its own simulated scan",
        ),
    ]


@hookimpl
def sbrdf_node_kinds():
    from .calibration import DarkFrame, FlatField

    return [DarkFrame, FlatField]


@hookimpl
def sbrdf_artifact_kinds():
    from .calibration import DARK_FRAME, FLAT_FIELD

    return [DARK_FRAME, FLAT_FIELD]
