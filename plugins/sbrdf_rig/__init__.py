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

Everything else (simulators in :mod:`sbrdf_rig.sim`, :mod:`sbrdf_rig.kinematics`,
:mod:`sbrdf_rig.planning`) is a library for capture sources and tools; see
``docs/acquisition-rig.md``.  This module imports nothing heavy.
"""

from sbrdf_core.params import Param
from sbrdf_core.plugin import PluginSpec, hookimpl

_LINK_PARAMS = (
    Param("port", "str", doc="serial device path, e.g. /dev/ttyUSB0 or a simulator's pty"),
    Param("baudrate", "int", 9600, "line speed", choices=(1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)),
    Param("timeout_s", "float", 1.0, "how long to wait for a complete reply", bounds=(0.001, 60.0), unit="s"),
    Param("retries", "int", 3, "extra attempts after a dropped/garbled reply or a missed position", bounds=(0, 20)),
    Param("tolerance_deg", "float", 0.05, "largest accepted difference between target and read-back position",
          bounds=(0.0, 10.0), unit="deg"),
    Param("move_timeout_s", "float", 60.0, "longest a single move may take", bounds=(0.01, 3600.0), unit="s"),
)

PTU_PARAMS = _LINK_PARAMS + (
    Param("pan_limits_deg", "list", [-159.0, 159.0], "pan soft limits [low, high], intersected with the unit's",
          length=2, item="float", bounds=(-360.0, 360.0), unit="deg"),
    Param("tilt_limits_deg", "list", [-47.0, 31.0], "tilt soft limits [low, high], intersected with the unit's",
          length=2, item="float", bounds=(-360.0, 360.0), unit="deg"),
    Param("speed_deg_s", "float", 20.0, "pan and tilt speed", bounds=(0.01, 1000.0), unit="deg/s"),
    Param("resolutions_arcsec", "list", [185.1428, 92.5714, 46.2857, 23.1428, 11.5714, 5.7857],
          "resolutions the controller model can report (PTU-46 family by default); a PR/TR reading must be one of "
          "them and read the same twice; [] checks agreement only", item="float", bounds=(1e-6, None), unit="arcsec"),
)

INDEXER_PARAMS = _LINK_PARAMS + (
    Param("axis", "int", 1, "controller axis number", bounds=(1, 4)),
    Param("gear_ratio", "float", 90.0, "motor revolutions per output revolution", bounds=(1e-3, None)),
    Param("limits_deg", "list", [10.0, 175.0], "soft limits [low, high] of the output shaft (light arm: 10-175 deg)",
          length=2, item="float", bounds=(-3600.0, 3600.0), unit="deg"),
    Param("speed_deg_s", "float", 20.0, "output-shaft speed", bounds=(0.01, 1000.0), unit="deg/s"),
    Param("acceleration_deg_s2", "float", 40.0, "output-shaft acceleration", bounds=(0.01, 10000.0), unit="deg/s^2"),
    Param("poll_s", "float", 0.01, "status polling interval while a move runs", bounds=(0.0, 1.0), unit="s"),
)


@hookimpl
def sbrdf_devices():
    return [
        PluginSpec("ptu", "sbrdf_rig.ptu:PanTiltUnit", PTU_PARAMS,
                   summary="Pan-tilt unit over serial, Directed Perception PTU command set (PP/TP, A, H)"),
        PluginSpec("indexer", "sbrdf_rig.indexer:Indexer", INDEXER_PARAMS,
                   summary="Rotary indexer over serial, Compumotor 6000-series language (D, GO, TPE, LS)"),
    ]


GONIO_PARAMS = (
    Param("path", "str", doc="capture folder written pose by pose (resumed if a run was interrupted), relative to "
          "the graph file", extra={"path": True}),
    Param("motors", "dict", doc="motor name -> {device: ptu|indexer|<any device plugin>, params: {port: /dev/ttyUSB0 | sim, ...}, "
          "axes: {joint: driver axis}}; joints pan, tilt, roll, light; axes default ptu {pan: pan_deg, tilt: tilt_deg}, "
          "indexer {light: angle_deg}; port: sim starts the device's pty simulator in-process"),
    Param("camera", "dict", {"device": "virtual-camera", "params": {}}, "camera device {device, params}"),
    Param("light", "dict", None, "the manifest's light section {type, intensity}; default the camera device's light_info()",
          nullable=True),
    Param("geometry", "dict", {}, "rig geometry: RigGeometry fields (distances, offsets, encoder zeros, *_limits_deg "
          "- also the planner's limits)"),
    Param("plan", "dict", {"theta_d_deg": 20.0, "isotropic": True},
          "poses: {angles_deg: [[pan, tilt, roll, light], ...]} or planner settings {theta_d_deg, isotropic, source, "
          "step_deg, max_theta_i_deg, max_theta_r_deg}"),
    Param("exposures", "dict", {"times_s": [1.0]}, "exposure brackets: {times_s: [t, ...] (all poses) or [[...], ...] "
          "(per pose)} or the exposure planner {diffuse_time_s, highlight_time_s, ...}"),
    Param("read", "dict", {}, "parameters of the folder plugin that reads poses back (response, response_method, "
          "response_poses, saturation, underexposure, colour_matrix)"),
    Param("settle_s", "float", 0.0, "wait after the motors stop before photographing (arm vibration)", bounds=(0.0, 600.0),
          unit="s"),
    Param("image_format", "str", "png", "file format of 8/16-bit images (float images are always EXR)",
          choices=("png", "tif")),
    Param("durable", "bool", True, "fsync every image and journal line (crash-safe against power loss)"),
)


@hookimpl
def sbrdf_captures():
    return [
        PluginSpec("gonio", "sbrdf_rig.gonio:GonioCapture", GONIO_PARAMS,
                   summary="Drive the gonioreflectometer (motors + camera) through a pose plan into an "
                           "sbrdf-capture/1 folder, resumably"),
    ]
