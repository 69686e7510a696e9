"""Camera devices: the virtual gonioreflectometer camera, and the ``virtual-folder`` capture source.

Devices are not graph nodes: capture sources (a ``gonio`` rig, the
``virtual-folder`` source below, tests, the capture benchmark) create them
with ``registry.create("device", name, params)``.  ``virtual-folder``
(:mod:`sbrdf_cameras.capture`) is a Capture plugin: it photographs a camera
device into an ``sbrdf-capture/1`` folder and reads it back as ``folder``
does, so a graph can make its own simulated scan.  Each contribution's
parameters are declared in :mod:`.declarations`, which imports no driver;
implementation modules are imported only when a device or source is created.  The calibration captures are node kinds
of their own (``DarkFrame``, ``FlatField``: :mod:`sbrdf_cameras.calibration`),
whose artifacts the Capture node's ``dark`` and ``flat`` inputs take.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_devices():
    return [
        PluginSpec(
            "virtual-camera",
            "sbrdf_cameras.virtual:VirtualCamera",
            params=declarations.VIRTUAL,
            summary="Simulated camera photographing a known SBRDF on an ArUco carrier under a point light",
        ),
        PluginSpec("pylon", "sbrdf_cameras.pylon:PylonCamera", params=declarations.PYLON,
                   summary="Basler camera through pypylon (PYLON_CAMEMU=N emulates N cameras)"),
        PluginSpec("aravis", "sbrdf_cameras.aravis:AravisCamera", params=declarations.ARAVIS,
                   summary="GigE Vision / USB3 Vision camera through Aravis (arv-fake-gv-camera-0.8 simulates one)"),
        PluginSpec("genicam", "sbrdf_cameras.genicam:GenICamCamera", params=declarations.GENICAM,
                   summary="GenICam camera through its vendor's GenTL producer (.cti) and harvesters (viky.cti "
                           "simulates three)"),
        PluginSpec("uvc", "sbrdf_cameras.uvc:UVCCamera", params=declarations.UVC,
                   summary="UVC webcam or capture card through OpenCV VideoCapture (a file stands in for one)"),
        PluginSpec("gphoto", "sbrdf_cameras.gphoto:GPhotoCamera", params=declarations.GPHOTO,
                   summary="DSLR or mirrorless camera over USB (PTP) through python-gphoto2"),
    ]


@hookimpl
def sbrdf_captures():
    return [
        PluginSpec(
            "virtual-folder",
            "sbrdf_cameras.capture:VirtualFolderCapture",
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
