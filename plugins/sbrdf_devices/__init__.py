"""Devices: the gonioreflectometer's motor controllers and the cameras.

Devices are not graph nodes: capture sources (``gonio``, ``virtual-folder``),
the calibration nodes, tests and the capture benchmark create them with
``registry.create("device", name, params)``.  Registers, as ``device``
plugins:

motor controllers (:mod:`.motors`, serial, each with a pty simulator in :mod:`.motors.sim`)
    ``ptu`` (:class:`.motors.ptu.PanTiltUnit`, Directed Perception PTU command set),
    ``indexer`` (:class:`.motors.indexer.Indexer`, Compumotor 6000-series command language);
cameras (:mod:`.cameras`)
    ``virtual-camera`` (:class:`.cameras.virtual.VirtualCamera`, a simulated camera photographing a known
    SBRDF), and the frame cameras ``pylon``, ``aravis``, ``genicam``, ``uvc``, ``gphoto``.

Each device's parameters are declared in :mod:`.declarations`, which imports
no driver (no pyserial, camera SDK, OpenCV or NumPy); a driver module is
imported only when its device is created.  What drivers share with other
packages (the serial link, motor-controller base and pty simulator base, the
camera base and protocol, the rig kinematics) is in :mod:`sbrdf_lib.serial`,
:mod:`sbrdf_lib.camera` and :mod:`sbrdf_lib.rig_geometry`.  See
``docs/acquisition-rig.md``.
"""

from sbrdf_core.plugin import PluginSpec, hookimpl

from . import declarations


@hookimpl
def sbrdf_devices():
    return [
        PluginSpec("ptu", "sbrdf_devices.motors.ptu:PanTiltUnit", params=declarations.PTU,
                   summary="Pan-tilt unit over serial, Directed Perception PTU command set (PP/TP, A, H)"),
        PluginSpec("indexer", "sbrdf_devices.motors.indexer:Indexer", params=declarations.INDEXER,
                   summary="Rotary indexer over serial, Compumotor 6000-series language (D, GO, TPE, LS)"),
        PluginSpec(
            "virtual-camera",
            "sbrdf_devices.cameras.virtual:VirtualCamera",
            params=declarations.VIRTUAL,
            summary="Simulated camera photographing a known SBRDF on an ArUco carrier under a point light",
        ),
        PluginSpec("pylon", "sbrdf_devices.cameras.pylon:PylonCamera", params=declarations.PYLON,
                   summary="Basler camera through pypylon (PYLON_CAMEMU=N emulates N cameras)"),
        PluginSpec("aravis", "sbrdf_devices.cameras.aravis:AravisCamera", params=declarations.ARAVIS,
                   summary="GigE Vision / USB3 Vision camera through Aravis (arv-fake-gv-camera-0.8 simulates one)"),
        PluginSpec("genicam", "sbrdf_devices.cameras.genicam:GenICamCamera", params=declarations.GENICAM,
                   summary="GenICam camera through its vendor's GenTL producer (.cti) and harvesters (viky.cti "
                           "simulates three)"),
        PluginSpec("uvc", "sbrdf_devices.cameras.uvc:UVCCamera", params=declarations.UVC,
                   summary="UVC webcam or capture card through OpenCV VideoCapture (a file stands in for one)"),
        PluginSpec("gphoto", "sbrdf_devices.cameras.gphoto:GPhotoCamera", params=declarations.GPHOTO,
                   summary="DSLR or mirrorless camera over USB (PTP) through python-gphoto2"),
    ]
