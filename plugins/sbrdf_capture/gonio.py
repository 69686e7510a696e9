"""gonio: drive the gonioreflectometer through a pose plan into a capture folder, pose by pose.

This is the capture source that joins the rig's pieces: the serial motor
drivers (``ptu``, ``indexer`` devices), the kinematics and planner, a camera
device (``virtual-camera``, or any device with the same protocol), and the
crash-safe ``sbrdf-capture/1`` writer.  The Capture node sees it like any
other source: :meth:`GonioCapture.describe` gives the nominal poses,
:meth:`GonioCapture.read_pose` one linear HDR image per pose.

Why the folder sits in the middle: a real capture runs for hours and can be
killed at any moment.  Every pose is written to the folder (images first,
then one journal line) *before* the Capture node stores it, and every image
the node stores is read back from the folder through the ``folder`` plugin's
own code (:meth:`sbrdf_capture.folder.FolderCapture.read_record`).  So

* a killed run resumes from the folder's journal: poses already journaled
  are read back, not taken again, and the rest are taken under the same
  file names (no image lost or duplicated);
* the finished folder is an ordinary scan: reading it later with the
  ``folder`` plugin gives the same images;
* a resumed capture equals an uninterrupted one, because the drivers make
  absolute moves and the camera's random effects are seeded per pose.

Per pose not yet in the journal (in plan order, one at a time, in this
process: the source is ``sequential``): move every motor (blocking, read
back and verified by the driver), wait ``settle_s``, photograph each bracket
exposure at the pose the motors *report* (read-back angles through the
kinematics, so a motor that stops within tolerance but off target shows up
in the images as it would on a real rig), ``write_pose``.  The folder
records that read-back pose (plus target and read-back motor angles under
``motors``); the CaptureSet carries the nominal planned poses (registration
measures the real ones).

Motors connect in :meth:`~GonioCapture.describe` (which the runner calls only
when the node actually runs, never for a cached node): every planned angle is
checked against the drivers' soft limits (and the rig geometry's) *before
anything moves*.  A motor fault (:class:`~sbrdf_lib.serial.errors.DeviceError`)
halts every motor and stops the capture with :class:`GonioCaptureError`,
naming the pose, the motor, its port and the command; the folder then holds
exactly the completed poses and the CaptureSet stays incomplete.

**Frame cameras** (``pylon``, ``aravis``, ``uvc``, ``gphoto``: any device with
:class:`~sbrdf_core.contracts.FrameCamera`'s API) know nothing of the sample or
the rig, so the source needs ``sample`` (the manifest's sample section: size
and fiducials) and ``intrinsics`` (``K``, ``dist`` from a calibration) beside
them; the camera's identity and settings (``info()``) go into the manifest's
``camera.device``.  The camera opens in :meth:`describe` with the motors, and
every planned exposure is checked against its range there, before anything
moves.  Per pose, after the motors report their positions and ``settle_s``
has passed, each bracket exposure is set (the time the camera actually uses
is recorded as the exposure's ``time_s``, the planned one under
``frames.requested_s``) and one frame grabbed.  Camera faults, like motor
faults, stop the capture with a :class:`GonioCaptureError` (``motor`` is
``"camera"``) and leave the folder with exactly the completed poses:

* the camera disappears (:class:`~sbrdf_lib.camera.CameraLost`): no retry;
* a frame times out or arrives incomplete (:class:`~sbrdf_lib.camera.FrameTimeout`):
  the trigger is repeated up to ``frame_retries`` times, then the error;
* the camera refuses an exposure (:class:`~sbrdf_lib.camera.ExposureRefused`):
  refused for the whole plan before any motion, or at the pose if it happens later;
* a saturated frame: its saturated pixels are masked when the pose is read
  (as for any camera) and the share is recorded per exposure under
  ``frames.saturated``; with ``max_saturated_fraction`` a pose whose shortest
  exposure saturates more than that share of pixels stops the capture
  (shorten the bracket or lower the gain, then resume).

``port: sim`` in a motor's parameters starts the pty simulator its driver
names (``ptu``'s and ``indexer``'s are in :mod:`sbrdf_devices.motors.sim`)
inside this process and connects the real driver to it, so
``graphs/gonio-virtual.yaml`` runs the whole rig without hardware.
"""

from __future__ import annotations

import json
import logging
import math
import time
import weakref
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sbrdf_core.contracts import optional
from sbrdf_core.errors import ParameterError, SbrdfError
from sbrdf_core.nodes.capture import CaptureDescription
from sbrdf_lib.camera import CameraError, CameraLost, ExposureRefused, FrameTimeout, saturated_fraction
from sbrdf_lib.capture_folder import (
    MANIFEST,
    CaptureFolderError,
    CaptureFolderWriter,
    load_manifest,
    manifest_sections,
    parse_manifest,
)
from sbrdf_lib.rig_geometry import RigGeometry, forward
from sbrdf_lib.serial.errors import DeviceError, LinkLost, SoftLimitError

from .declarations import GONIO
from .read_back import ReadBack

if TYPE_CHECKING:
    from sbrdf_core.registry import Registry

    from .folder import FolderCapture

log = logging.getLogger(__name__)

#: Rig joints, in the order of plan angles (``PosePlan.angles_deg``) and :func:`forward`'s arguments.
JOINTS = ("pan", "tilt", "roll", "light")
#: ``port`` value that starts the device's simulator in this process.
SIM_PORT = "sim"
#: Joint -> driver axis when a motor's ``axes`` is omitted.
DEFAULT_AXES = {"ptu": {"pan": "pan_deg", "tilt": "tilt_deg"}, "indexer": {"light": "angle_deg"}}
#: ``port: sim`` starts the simulator a driver names in its ``simulator = "package.module:Class"`` class
#: attribute (constructed with no arguments): the built-in drivers exactly as third-party ones.

PLANNER_KEYS = {"theta_d_deg", "isotropic", "source", "step_deg", "max_theta_i_deg", "max_theta_r_deg"}
EXPOSURE_PLANNER_KEYS = {"diffuse_time_s", "highlight_time_s", "highlight_halfwidth_deg", "field_halfwidth_deg",
                         "stops_per_exposure", "max_exposures", "min_time_s", "max_time_s"}
#: ``folder`` parameters the gonio source sets itself (everything else may be given under ``read``).
READ_RESERVED = {"path", "allow_incomplete", "dark_frame", "dark_time_s"}


class GonioCaptureError(DeviceError):
    """The rig failed during a capture; names the pose, the motor, its port and the command.

    ``pose`` is the plan index of the pose being taken, ``motor`` the name of
    the motor in the ``motors`` parameter, ``cause`` the driver's error.
    """

    def __init__(self, message: str, *, pose: int, motor: str, cause: DeviceError):
        SbrdfError.__init__(self, message)
        self.device, self.port, self.command, self.received = cause.device, cause.port, cause.command, cause.received
        self.pose, self.motor, self.cause = pose, motor, cause


@dataclass
class Motor:
    """One motor controller of the rig, as configured, and its driver once connected."""

    name: str
    device: str
    values: dict          # resolved driver parameters (port may still be "sim")
    axes: dict            # joint -> driver axis
    driver: Any = None
    simulator: Any = None

    @property
    def port(self) -> str:
        return self.driver.port if self.driver is not None else str(self.values.get("port"))


@dataclass
class _Devices:
    """What must be halted and released, kept apart from the source so a finalizer can reach it."""

    motors: list[Motor] = field(default_factory=list)
    camera: Any = None  # a frame camera once opened (the virtual camera holds nothing to release)

    def close(self) -> None:
        if self.camera is not None:
            camera, self.camera = self.camera, None
            try:
                camera.close()
            except Exception:  # noqa: BLE001 - closing must reach every device
                log.exception("gonio: closing the camera failed")
        for m in self.motors:
            if m.driver is not None:
                try:
                    m.driver.close()  # halts (best effort) and releases the port; idempotent
                except Exception:  # noqa: BLE001 - closing must reach every motor
                    log.exception("gonio: closing motor %r failed", m.name)
            if m.simulator is not None:
                m.simulator.stop()
                m.simulator = None
            m.driver = None


def _jsonable(value: Any) -> Any:
    """What ``value`` reads back as from capture.json (tuples -> lists, numpy -> Python)."""
    return json.loads(json.dumps(value, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def _requested(pose) -> list[float]:
    """The exposure times a recorded pose was planned with (a frame camera's actual times may be rounded)."""
    requested = (pose.extra.get("frames") or {}).get("requested_s")
    return [float(t) for t in requested] if isinstance(requested, list) else [e.time_s for e in pose.exposures]


def _fmt_angles(angles: dict) -> str:
    return ", ".join(f"{k}={v:.4f}" for k, v in angles.items())


class GonioCapture(ReadBack):
    """Capture source driving motors + camera through a pose plan (see the module docstring)."""

    source = "gonio"
    #: Hardware: the runner takes poses one at a time, in plan order, in this process.
    sequential = True

    params = GONIO

    @staticmethod
    def check_params(params, registry=None) -> list[tuple[str, str]]:
        """``read:`` at validation: only the folder reader's parameters the source does not set itself, each
        checked by the ``folder`` plugin's declarations (else the first pose is captured before it fails)."""
        read = params.get("read") or {}
        if not isinstance(read, dict):
            return []
        bad = sorted(READ_RESERVED & set(read))
        if bad:
            return [("read", f"read: {bad} are set by the gonio source itself; give only response, response_method, "
                             "response_poses, saturation, underexposure, colour_matrix")]
        if registry is None or "folder" not in registry.specs.get("capture", {}):
            return []
        from sbrdf_core.params import resolve

        declared = [p for p in registry.get("capture", "folder").params or () if p.name not in READ_RESERVED]
        _, problems = resolve(declared, read, "read (the folder reader)")
        return [("read", msg) for _, msg in problems]

    def __init__(self, *, path: str, motors: dict, camera: dict = {"device": "virtual-camera", "params": {}},  # noqa: B006
                 light: dict | None = None, geometry: dict = {}, plan: dict = {"theta_d_deg": 20.0, "isotropic": True},  # noqa: B006
                 exposures: dict = {"times_s": [1.0]}, read: dict = {}, settle_s: float = 0.0,  # noqa: B006
                 image_format: str = "png", durable: bool = True, sample: dict | None = None,
                 intrinsics: dict | None = None, frame_retries: int = 1, max_saturated_fraction: float | None = None):
        self.path = Path(str(path)).expanduser()
        self.motors = self._parse_motors(motors)
        self.camera_config = self._parse_device(camera, "camera")
        self.light = None if light is None else dict(light)
        self.geometry = self._parse_geometry(geometry)
        self.plan_config = dict(plan)
        self.exposure_config = dict(exposures)
        self._check_plan_config()
        self.read_config = dict(read)
        bad = sorted(READ_RESERVED & set(self.read_config))
        if bad:
            raise ParameterError(f"gonio: read: {bad} are set by the gonio source itself; give only response, "
                                 "response_method, response_poses, saturation, underexposure, colour_matrix")
        self.settle_s, self.image_format, self.durable = float(settle_s), image_format, bool(durable)
        self.sample = None if sample is None else dict(sample)
        self.intrinsics = None if intrinsics is None else dict(intrinsics)
        self.frame_retries, self.max_saturated_fraction = int(frame_retries), max_saturated_fraction
        #: Frame camera (physical) rather than a scene-rendering one; known once bound.
        self.frame_camera = False
        #: Seconds spent, summed over the poses this process took: motion, settle, exposure, transfer, write.
        self.timings = dict.fromkeys(("motion", "settle", "exposure", "transfer", "write"), 0.0)
        self.registry: Registry | None = None
        #: The camera device: a scene-rendering one (``photograph``, ``sample_info``...) bound in :meth:`bind`, or a
        #: frame camera (``grab``, ``set_exposure``...) opened in :meth:`_connect`; ``frame_camera`` says which.
        self.camera: Any = None
        self.reader: FolderCapture | None = None
        #: The folder writer; :meth:`_start` opens it unless the folder already holds the complete capture.
        self.writer: CaptureFolderWriter | None = None
        self._plan: tuple[np.ndarray, list[list[float]]] | None = None
        self._started = False
        self._complete = False
        self._devices = _Devices(self.motors)
        self._finalizer = weakref.finalize(self, self._devices.close)

    # -- configuration ------------------------------------------------------------------------------

    @staticmethod
    def _parse_device(config, where: str) -> tuple[str, dict]:
        if not isinstance(config, dict) or "device" not in config:
            raise ParameterError(f"gonio: {where}: expected {{device: <device plugin>, params: {{...}}}}, got {config!r}")
        accepted = {"device", "params"} | ({"axes"} if where != "camera" else set())
        unknown = sorted(set(config) - accepted)
        if unknown:
            raise ParameterError(f"gonio: {where}: unknown key(s) {unknown}; accepted: {sorted(accepted)}")
        params = config.get("params") or {}
        if not isinstance(params, dict):
            raise ParameterError(f"gonio: {where}.params: expected a mapping, got {params!r}")
        return str(config["device"]), dict(params)

    def _parse_motors(self, motors) -> list[Motor]:
        if not isinstance(motors, dict) or not motors:
            raise ParameterError("gonio: motors: expected a mapping of motor name -> {device, params, axes}, e.g. "
                                 "{sample_pan: {device: ptu, params: {port: sim}, axes: {pan: pan_deg}}}")
        out: list[Motor] = []
        driven: dict[str, str] = {}  # joint -> motor name
        for name, config in motors.items():
            device, params = self._parse_device(config, f"motors.{name}")
            axes = config.get("axes", DEFAULT_AXES.get(device))
            if not isinstance(axes, dict) or not axes:
                raise ParameterError(f"gonio: motors.{name}.axes: give the joints this {device!r} drives, "
                                     f"as {{joint: driver axis}} with joints among {list(JOINTS)}")
            for joint in axes:
                if joint not in JOINTS:
                    raise ParameterError(f"gonio: motors.{name}.axes: unknown joint {joint!r}; joints are {list(JOINTS)}")
                if joint in driven:
                    raise ParameterError(f"gonio: joint {joint!r} is driven by two motors ({driven[joint]!r} and {name!r})")
                driven[joint] = name
            if len(set(axes.values())) != len(axes):
                raise ParameterError(f"gonio: motors.{name}.axes: one driver axis drives two joints: {axes}")
            out.append(Motor(str(name), device, params, {str(k): str(v) for k, v in axes.items()}))
        return out

    def _parse_geometry(self, geometry) -> RigGeometry:
        known = {f.name for f in fields(RigGeometry)}
        unknown = sorted(set(geometry) - known)
        if unknown:
            raise ParameterError(f"gonio: geometry: unknown field(s) {unknown}; RigGeometry fields: {sorted(known)}")
        values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in geometry.items()}
        return RigGeometry(**values)

    def _check_plan_config(self) -> None:
        plan = self.plan_config
        if ("angles_deg" in plan) == ("theta_d_deg" in plan):
            raise ParameterError("gonio: plan: give either angles_deg (explicit [pan, tilt, roll, light] per pose) or "
                                 f"theta_d_deg (+ planner settings {sorted(PLANNER_KEYS - {'theta_d_deg'})}), not "
                                 f"{'both' if plan else 'neither'}")
        allowed = {"angles_deg"} if "angles_deg" in plan else PLANNER_KEYS
        unknown = sorted(set(plan) - allowed)
        if unknown:
            raise ParameterError(f"gonio: plan: unknown key(s) {unknown}; accepted here: {sorted(allowed)}")
        exp = self.exposure_config
        if ("times_s" in exp) == ("diffuse_time_s" in exp or "highlight_time_s" in exp):
            raise ParameterError("gonio: exposures: give either times_s (one bracket for all poses, or one per pose) or "
                                 "diffuse_time_s + highlight_time_s (the exposure planner)")
        allowed = {"times_s"} if "times_s" in exp else EXPOSURE_PLANNER_KEYS
        unknown = sorted(set(exp) - allowed)
        if unknown:
            raise ParameterError(f"gonio: exposures: unknown key(s) {unknown}; accepted here: {sorted(allowed)}")

    # -- plugins ------------------------------------------------------------------------------------

    def bind(self, registry) -> None:
        """Resolve devices and the folder reader through the run's registry, without touching hardware.

        The runner binds a plugin even when its node turns out to be cached,
        so drivers (whose constructors open the serial port and talk to the
        controller) are only *validated* here; they connect in :meth:`describe`.
        """
        from sbrdf_core.params import resolve

        self.registry = registry
        for m in self.motors:
            spec = registry.get("device", m.device)
            values, problems = resolve(spec.params, m.values, f"gonio motors.{m.name} (device {m.device!r})")
            if problems:
                raise ParameterError("; ".join(msg for _, msg in problems))
            driver = registry.load(spec)
            if values.get("port") == SIM_PORT and not getattr(driver, "simulator", None):
                raise ParameterError(f"gonio: motors.{m.name}: port: {SIM_PORT} needs a simulator, and device "
                                     f"{m.device!r} has none (a driver class names its simulator in a 'simulator' "
                                     "attribute)")
            axes = getattr(driver, "axes", ())
            bad = sorted(a for a in m.axes.values() if a not in axes)
            if bad:
                raise ParameterError(f"gonio: motors.{m.name}.axes: {m.device!r} has no axis {bad}; its axes are {list(axes)}")
            m.values = values
        device, params = self.camera_config
        impl = registry.load(registry.get("device", device))
        self.frame_camera = hasattr(impl, "grab") and not hasattr(impl, "photograph")
        if self.frame_camera:
            # A physical camera opens in describe() with the motors; here its parameters are only checked.
            values, problems = resolve(registry.get("device", device).params, params, f"gonio camera (device {device!r})")
            if problems:
                raise ParameterError("; ".join(msg for _, msg in problems))
            self.camera_config = (device, values)
            missing = [k for k in ("sample", "intrinsics") if getattr(self, k) is None]
            if missing:
                raise ParameterError(f"gonio: camera {device!r} is a frame camera, which knows nothing of the sample or "
                                     f"its own optics: give {' and '.join(missing)} (sample: {{size_mm, fiducials}}, "
                                     "intrinsics: {K, dist} from a calibration)")
        else:
            self.camera = registry.create("device", device, params)
            if optional(self.camera, "bind", "device") is not None:
                self.camera.bind(registry)
        self.reader = registry.create("capture", "folder", {**self.read_config, "path": str(self.path)})

    def __dask_tokenize__(self):
        return ("sbrdf-gonio", str(self.path), id(self))

    # -- the plan ---------------------------------------------------------------------------------

    def planned(self) -> tuple[np.ndarray, list[list[float]]]:
        """``(angles (P, 4) pan/tilt/roll/light degrees, exposure times per pose)`` of the plan."""
        if self._plan is None:
            angles = self._plan_angles()
            self._plan = angles, self._plan_exposures(angles)
        return self._plan

    def _plan_angles(self) -> np.ndarray:
        plan = self.plan_config
        if "angles_deg" in plan:
            try:
                angles = np.asarray(plan["angles_deg"], dtype=np.float64)
            except (TypeError, ValueError):
                angles = np.zeros((0, 0))
            if angles.ndim != 2 or angles.shape[1] != 4 or not len(angles) or not np.isfinite(angles).all():
                raise ParameterError("gonio: plan.angles_deg: expected a non-empty list of finite "
                                     "[pan, tilt, roll, light] angles (degrees)")
            return angles
        from .planning import plan_poses

        kwargs = {k: plan[k] for k in ("source", "step_deg", "max_theta_i_deg", "max_theta_r_deg") if k in plan}
        try:
            result = plan_poses(self.geometry, float(plan["theta_d_deg"]), isotropic=bool(plan.get("isotropic", True)),
                                **kwargs)
        except ValueError as e:
            raise ParameterError(f"gonio: plan: {e}") from None
        if not len(result):
            raise ParameterError(f"gonio: plan: the planner found no reachable pose for {plan} within the geometry's limits")
        return np.asarray(result.angles_deg, np.float64)

    def _plan_exposures(self, angles: np.ndarray) -> list[list[float]]:
        P = len(angles)
        exp = self.exposure_config
        if "times_s" in exp:
            given = exp["times_s"]
            if isinstance(given, (int, float)):
                given = [given]
            if isinstance(given, list) and given and all(isinstance(g, (int, float)) for g in given):
                times = [[float(g) for g in given]] * P
            elif isinstance(given, list) and len(given) == P and all(isinstance(g, list) for g in given):
                times = [[float(x) for x in g] for g in given]
            else:
                raise ParameterError(f"gonio: exposures.times_s: expected one bracket (1-3 times) for every pose or "
                                     f"one bracket per pose ({P} lists), got {given!r}")
        else:
            from .planning import plan_exposures

            missing = sorted({"diffuse_time_s", "highlight_time_s"} - set(exp))
            if missing:
                raise ParameterError(f"gonio: exposures: the exposure planner needs {missing}")
            wi, wo = forward(self.geometry, *angles.T).directions()
            kwargs: dict[str, Any] = {k: float(v) for k, v in exp.items()}
            if "max_exposures" in exp:
                kwargs["max_exposures"] = self._max_exposures()  # a count: a float one made the planner fail
            table = plan_exposures(wi, wo, **kwargs)
            times = [[float(x) for x in row if np.isfinite(x)] for row in table]
        for i, bracket in enumerate(times):
            if not 1 <= len(bracket) <= 3 or not all(math.isfinite(x) and x > 0 for x in bracket):
                raise ParameterError(f"gonio: exposures: pose {i} has bracket {bracket}; a bracket is 1 to 3 positive times")
        return times

    def _max_exposures(self) -> int:
        """``exposures.max_exposures`` as the planner's count of exposures per bracket (a whole number)."""
        given = self.exposure_config["max_exposures"]
        if isinstance(given, bool) or not isinstance(given, (int, float)) or given != int(given) or given < 1:
            raise ParameterError(f"gonio: exposures.max_exposures: expected a whole number >= 1, got {given!r}")
        return int(given)

    # -- capture source protocol ------------------------------------------------------------------

    def describe(self) -> CaptureDescription:
        """Nominal poses of the plan; connects the rig and checks every angle against the limits first."""
        angles, times = self.planned()
        if self.registry is None:
            from sbrdf_core.registry import default_registry

            self.bind(default_registry())
        nominal = forward(self.geometry, *angles.T)
        self._check_light_above(angles, np.asarray(nominal.light_pos_mm, np.float64))
        if not self._started:
            self._start(angles, times)
        header = parse_manifest({**self._header(), "complete": False, "poses": []}, f"{self.path} (gonio header)")
        mode = self._folder_reader().response_mode
        linear = mode == "linear" or header.camera.response == "linear"
        sample, camera, light = manifest_sections(header, linear)
        return CaptureDescription(
            height=header.camera.height, width=header.camera.width,
            light_pos=np.asarray(nominal.light_pos_mm, np.float64),
            camera_R=np.asarray(nominal.camera_R, np.float64),
            camera_t=np.asarray(nominal.camera_t, np.float64),
            exposure_s=np.array([min(b) for b in times], np.float64),
            sample=sample, camera=camera, light=light,
        )

    def read_pose(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Take the poses up to ``index`` that the folder lacks, then read pose ``index`` back from the folder."""
        angles, times = self.planned()
        if not self._started:
            self.describe()
        if not self._complete:
            # A response curve recovered from brackets needs every pose, so then the whole scan comes first.
            last = len(angles) - 1 if self._needs_all_poses() else int(index)
            for j in range(last + 1):
                if j not in self._folder_writer().done_ids:
                    self._take(j, angles, times)
        if self._complete:
            return self._folder_reader().read_pose(int(index))
        return self._folder_reader().read_record(self._folder_writer().poses[int(index)], f"pose {int(index)}")

    # -- session ------------------------------------------------------------------------------------

    def _header(self) -> dict:
        """The capture.json header this capture writes (and a resumed one must match)."""
        if not hasattr(self, "_header_cache"):
            cam = self.camera
            if self.frame_camera:
                header = {"format": "sbrdf-capture/1", "sample": self.sample, "camera": self._frame_camera_section(),
                          "light": self.light if self.light is not None else {"type": "point", "intensity": 1.0},
                          "rig": self._rig()}
            else:
                header = {"format": "sbrdf-capture/1", "sample": cam.sample_info(), "camera": cam.camera_info(),
                          "light": self.light if self.light is not None else cam.light_info(), "rig": self._rig()}
                if hasattr(cam, "simulation_info"):
                    header["simulation"] = cam.simulation_info()
            self._header_cache = _jsonable(header)
        return self._header_cache

    def _rig(self) -> dict:
        """The manifest's ``rig`` record: what a resumed capture must have been planned with."""
        rig = {"source": "gonio", "geometry": asdict(self.geometry),
               "motors": {m.name: {"device": m.device, "axes": m.axes} for m in self.motors},
               "plan": self.plan_config, "exposures": self.exposure_config}
        return _jsonable(rig)

    def _frame_camera_section(self) -> dict:
        """The manifest's ``camera`` section of a frame camera: size, intrinsics, linearity, device record.

        A camera delivering linear codes declares ``response: linear``; any
        other leaves the response to be recovered from the brackets (or given
        to the reader).  Before the camera is open (a complete folder that is
        only read) the recorded section stands.
        """
        if self.camera is None:
            return self._recorded_camera
        assert self.intrinsics is not None, "bind() requires intrinsics with a frame camera"
        info = dict(self.camera.info())
        section = {"width": int(info.pop("width")), "height": int(info.pop("height")),
                   "K": self.intrinsics.get("K"), "dist": self.intrinsics.get("dist", [0.0] * 5)}
        if info.get("linear"):
            section["response"] = "linear"
        section["device"] = info
        return section

    def _folder_writer(self) -> CaptureFolderWriter:
        """The folder writer; poses are taken only after :meth:`_start` opened it (an unfinished capture)."""
        assert self.writer is not None, "gonio: a pose is taken or recorded before _start() opened the folder"
        return self.writer

    def _needs_all_poses(self) -> bool:
        mode = self._folder_reader().response_mode
        given = self._header()["camera"].get("response")
        return mode == "recover" or (mode == "auto" and not isinstance(given, dict) and given != "linear")

    def _start(self, angles: np.ndarray, times: list[list[float]]) -> None:
        self._started = True
        manifest = self.path / MANIFEST
        if manifest.exists():
            old = load_manifest(self.path)
            if old.extra.get("rig") != self._rig():
                raise CaptureFolderError(
                    f"{manifest}: holds a capture taken with a different rig, plan or exposures "
                    f"({'complete' if old.complete else 'unfinished'}); use another path or remove that folder")
            if old.complete:
                self._recorded_camera = old.header_json()["camera"]
                expected = parse_manifest({**self._header(), "complete": False, "poses": []}, str(manifest)).header_json()
                if old.header_json() != expected:
                    raise CaptureFolderError(f"{manifest}: holds a complete capture with a different sample, camera or "
                                             "light; use another path or remove that folder")
                self._check_recorded(old.poses, angles, times, complete=True)
                self._complete = True
                self._folder_reader().manifest = None  # read it as the folder plugin would
                log.info("gonio: %s already holds the complete capture; no motion", self.path)
                return
        self._connect()
        try:
            self._check_limits(angles)
            if self.frame_camera:
                self._check_exposures(times)
            extra = {k: v for k, v in self._header().items() if k not in ("format", "sample", "camera", "light")}
            h = self._header()
            self.writer = CaptureFolderWriter(self.path, h["sample"], h["camera"], h["light"],
                                              image_format=self.image_format, durable=self.durable, extra=extra)
            self._check_recorded(list(self.writer.poses.values()), angles, times, complete=False)
            if not self._needs_all_poses():
                self._folder_reader().attach(self.writer.manifest)
            if self.writer.done_ids:
                log.info("gonio: resuming %s: %d of %d poses already recorded", self.path, len(self.writer.done_ids),
                         len(angles))
            self._maybe_finish(len(angles))
        except BaseException:
            self._devices.close()
            raise

    def _check_recorded(self, poses, angles: np.ndarray, times: list[list[float]], complete: bool) -> None:
        """Poses already in the folder must be the plan's (a planner change must not mix two scans)."""
        P = len(angles)
        ids = sorted(p.id for p in poses)
        if complete and ids != list(range(P)):
            raise CaptureFolderError(f"{self.path / MANIFEST}: the complete capture there has pose ids {ids[:5]}... "
                                     f"({len(ids)} poses) but the plan has {P} poses; use another path")
        for p in poses:
            target = (p.extra.get("motors") or {}).get("target_deg")
            ok = (0 <= p.id < P and isinstance(target, dict)
                  and np.allclose([target.get(j, np.nan) for j in JOINTS], angles[p.id], rtol=0, atol=1e-9)
                  and np.allclose(sorted(_requested(p)), sorted(times[p.id])))
            if not ok:
                raise CaptureFolderError(f"{self.path / MANIFEST}: recorded pose {p.id} (motors {target}) is not pose "
                                         f"{p.id} of this plan; the folder belongs to another plan - use another path")

    def _connect(self) -> None:
        """Start ``port: sim`` simulators and open every driver (no motion: drivers only configure and query)."""
        from sbrdf_core.registry import import_path

        registry = self.registry
        assert registry is not None, "describe() binds the source before connecting the rig"
        try:
            for m in self.motors:
                values = dict(m.values)
                spec = registry.get("device", m.device)
                if values.get("port") == SIM_PORT:
                    cls = import_path(registry.load(spec).simulator)
                    m.simulator = self._simulator(cls, m.device, values).start()
                    values["port"] = m.simulator.port
                try:
                    m.driver = registry.load(spec)(**values)
                except DeviceError as e:
                    raise GonioCaptureError(f"gonio: motor {m.name!r} ({m.device} on {values['port']}) could not be "
                                            f"connected: {e}", pose=-1, motor=m.name, cause=e) from e
            if self.frame_camera:
                device, values = self.camera_config
                try:
                    self.camera = self._devices.camera = registry.load(registry.get("device", device))(**values)
                except CameraError as e:
                    raise GonioCaptureError(f"gonio: camera {device!r} could not be opened: {e}. Nothing moved",
                                            pose=-1, motor="camera", cause=e) from e
        except BaseException:
            self._devices.close()
            raise

    @staticmethod
    def _simulator(cls, device: str, values: dict):
        if device == "indexer":
            return cls(axes=int(values.get("axis", 1)), gear_ratio=float(values.get("gear_ratio", 90.0)))
        return cls()

    def _check_light_above(self, angles: np.ndarray, light: np.ndarray) -> None:
        """Refuse, before anything connects or moves, poses that put the light at or below the sample plane.

        There the light cannot reach the sample's surface; the capture folder
        refuses such a pose (docs/capture-folders.md), so the plan does first.
        """
        bad = np.flatnonzero(~(light[:, 2] > 0))
        if len(bad):
            i = int(bad[0])
            raise ParameterError(
                f"gonio: plan: {len(bad)} of {len(angles)} poses put the light at or below the sample plane (z <= 0), "
                f"where it cannot light the surface; first: pose {i} [pan, tilt, roll, light] = "
                f"{[round(float(a), 4) for a in angles[i]]} deg puts it at z = {light[i, 2]:.1f} mm "
                f"(poses {bad[:10].tolist()}{' ...' if len(bad) > 10 else ''}). Nothing moved; drop those poses or "
                "narrow the light/tilt angles")

    def _check_limits(self, angles: np.ndarray) -> None:
        """Refuse the plan before any motion if a pose leaves a driver's or the geometry's limits."""
        problems: list[tuple[np.ndarray, str, Motor | None]] = []  # (bad poses, message, motor or None: the rig)
        geo = self.geometry.limits
        driven: dict[str, tuple[Motor, str]] = {}
        for m in self.motors:
            for joint, axis in m.axes.items():
                driven[joint] = (m, axis)
        for k, joint in enumerate(JOINTS):
            col = angles[:, k]
            if joint not in driven:
                bad = np.flatnonzero(np.abs(col) > 1e-9)
                if len(bad):
                    problems.append((bad, f"{joint} = {col[bad[0]]:g} deg but no motor drives {joint} (it stays at 0)",
                                     None))
                continue
            lo, hi = geo[k]
            bad = np.flatnonzero((col < lo) | (col > hi))
            if len(bad):
                problems.append((bad, f"{joint} = {col[bad[0]]:g} deg is outside the rig geometry's "
                                      f"{joint}_limits_deg [{lo:g}, {hi:g}]", None))
            m, axis = driven[joint]
            lo, hi = m.driver.limits[axis]
            bad = np.flatnonzero((col < lo) | (col > hi))
            if len(bad):
                problems.append((bad, f"{joint} = {col[bad[0]]:g} deg is outside motor {m.name!r} ({m.device} on "
                                      f"{m.driver.port}) {axis} soft limits [{lo:g}, {hi:g}]", m))
        if problems:
            first = min(problems, key=lambda p: p[0][0])
            poses = sorted(set(np.concatenate([p[0] for p in problems]).tolist()))
            detail = "; ".join(f"pose {p[0][0]}: {p[1]} ({len(p[0])} pose{'s' if len(p[0]) > 1 else ''})"
                               for p in problems)
            culprit = first[2]
            error = SoftLimitError(
                f"the gonio plan is refused before any motion: {len(poses)} of {len(angles)} poses leave the limits - "
                f"{detail}. Narrow the plan (geometry *_limits_deg, or the explicit angles) or widen the motor limits",
                device=culprit.device if culprit else "rig geometry", port=culprit.driver.port if culprit else "")
            self._devices.close()
            raise error

    def _check_exposures(self, times: list[list[float]]) -> None:
        """Refuse, before any motion, a plan with exposure times the frame camera cannot take."""
        try:
            lo, hi = self.camera.exposure_range_s()
        except CameraError as e:
            self._devices.close()
            raise GonioCaptureError(f"gonio: the plan is refused before any motion: {e}", pose=-1, motor="camera",
                                    cause=e) from e
        bad = [(i, t) for i, bracket in enumerate(times) for t in bracket if not lo * (1 - 1e-9) <= t <= hi * (1 + 1e-9)]
        if bad:
            name = self.camera_config[0]
            cause = self.camera.error(ExposureRefused, f"exposure {bad[0][1]:g} s is outside the camera's range "
                                      f"[{lo:g}, {hi:g}] s", command=f"exposure {bad[0][1]:g} s")
            self._devices.close()
            raise GonioCaptureError(
                f"gonio: the plan is refused before any motion: {len(bad)} exposure(s) outside camera {name!r}'s range "
                f"[{lo:g}, {hi:g}] s, first pose {bad[0][0]} at {bad[0][1]:g} s. Change exposures (or the gain)",
                pose=bad[0][0], motor="camera", cause=cause)

    def _grab_bracket(self, index: int, bracket: list[float], n_poses: int) -> tuple[list, dict]:
        """Set each exposure and grab a frame, re-triggering after a timeout; ``(images, camera record)``."""
        cam, name = self.camera, self.camera_config[0]
        images, actual, saturated = [], [], []
        try:
            for k, ts in enumerate(bracket):
                used = cam.set_exposure(ts)
                for attempt in range(self.frame_retries + 1):
                    try:
                        frame = cam.grab(pose_id=index, exposure_index=k)
                        break
                    except FrameTimeout:
                        if attempt == self.frame_retries:
                            raise
                        log.warning("gonio: pose %d exposure %d: frame timeout, re-triggering (%d of %d)", index, k,
                                    attempt + 1, self.frame_retries)
                timing = getattr(cam, "last_timing", {})
                self.timings["exposure"] += timing.get("exposure", 0.0)
                self.timings["transfer"] += timing.get("transfer", 0.0)
                images.append((frame, used))
                actual.append(used)
                saturated.append(saturated_fraction(frame))
        except CameraError as e:
            done = len(self._folder_writer().done_ids)
            what = {CameraLost: "disappeared", FrameTimeout: f"delivered no frame after {self.frame_retries + 1} "
                    "triggers", ExposureRefused: "refused the exposure"}.get(type(e), "failed")
            raise GonioCaptureError(
                f"gonio: pose {index} of {n_poses} failed: camera {name!r} {what}: {e}. All motors halted; {self.path} "
                f"holds the {done} completed poses - fix the cause and re-run the graph to resume from pose {index}",
                pose=index, motor="camera", cause=e) from e
        shortest = int(np.argmin(bracket))
        if self.max_saturated_fraction is not None and saturated[shortest] > self.max_saturated_fraction:
            done = len(self._folder_writer().done_ids)
            cause = cam.error(CameraError, f"{saturated[shortest]:.1%} of the pixels saturated at {bracket[shortest]:g} s")
            raise GonioCaptureError(
                f"gonio: pose {index} of {n_poses}: the shortest exposure ({bracket[shortest]:g} s) saturates "
                f"{saturated[shortest]:.1%} of the pixels, over max_saturated_fraction {self.max_saturated_fraction:g}; "
                f"shorten the bracket or lower the gain, then re-run to resume from pose {index} ({done} poses kept)",
                pose=index, motor="camera", cause=cause)
        return images, {"requested_s": [float(t) for t in bracket], "saturated": saturated}

    def _take(self, index: int, angles: np.ndarray, times: list[list[float]]) -> None:
        """Move, settle, photograph the bracket at the read-back pose, record the pose."""
        target = dict(zip(JOINTS, (float(a) for a in angles[index])))
        read = {j: 0.0 for j in JOINTS}
        clock = time.perf_counter()
        try:
            for m in self.motors:
                goal = {axis: target[joint] for joint, axis in m.axes.items()}
                try:
                    position = m.driver.move_to(**goal)
                except DeviceError as e:
                    done = len(self._folder_writer().done_ids)
                    halted = ("Its port is gone (halt attempted, best effort); every other motor halted"
                              if isinstance(e, LinkLost) else "All motors halted")
                    raise GonioCaptureError(
                        f"gonio: pose {index} of {len(angles)} failed: motor {m.name!r} ({m.device} on {e.port or m.port}) "
                        f"moving to {_fmt_angles(goal)}: {e}. {halted}; {self.path} holds the {done} completed "
                        f"poses - fix the cause and re-run the graph to resume from pose {index}",
                        pose=index, motor=m.name, cause=e) from e
                for joint, axis in m.axes.items():
                    read[joint] = float(position[axis])
            clock = self._tick("motion", clock)
            if self.settle_s:
                time.sleep(self.settle_s)
            clock = self._tick("settle", clock)
            at = forward(self.geometry, *(read[j] for j in JOINTS))
            light, R, t = at.light_pos_mm[0], at.camera_R[0], at.camera_t[0]
            extra: dict[str, Any] = {"motors": {"target_deg": target, "read_deg": read}}
            if self.frame_camera:
                # The motors have reported their positions and settle_s has passed: only now is a frame triggered.
                images, extra["frames"] = self._grab_bracket(index, times[index], len(angles))
            else:
                images = [(self.camera.photograph(light, R, t, ts, pose_id=index, exposure_index=k), ts)
                          for k, ts in enumerate(times[index])]
                self.timings["transfer"] += time.perf_counter() - clock  # a rendered frame: no exposure to wait for
            clock = time.perf_counter()
            true = getattr(self.camera, "true_poses", {}).get(index)
            if true is not None:
                extra["simulation"] = {"true_light_pos_mm": true[0].tolist(), "true_R": true[1].tolist(),
                                       "true_t": true[2].tolist()}
            self._folder_writer().write_pose(index, light, R, t, images, extra=extra)
            self._tick("write", clock)
        except BaseException:
            self._devices.close()
            raise
        log.debug("gonio: pose %d/%d recorded at %s", index + 1, len(angles), _fmt_angles(read))
        self._maybe_finish(len(angles))

    def _tick(self, phase: str, since: float) -> float:
        now = time.perf_counter()
        self.timings[phase] += now - since
        return now

    def _maybe_finish(self, n_poses: int) -> None:
        if len(self._folder_writer().done_ids) == n_poses and not self._complete:
            self._folder_writer().finish()
            self._devices.close()
            self._complete = True
            self._folder_reader().manifest = None  # from now on the finished folder is read exactly as `folder` reads it
            log.info("gonio: capture complete: %s (%d poses)", self.path, n_poses)

    def close(self) -> None:
        """Halt the motors, release the ports and stop simulators (also done on completion and on errors)."""
        self._devices.close()
