"""virtual-folder: photograph the virtual camera into a capture folder, then read it as ``folder`` does.

A graph that starts from a simulated scan needs no preparation step: the
Capture node's ``virtual-folder`` source renders every pose with a camera
device (``virtual-camera`` by default) into a real ``sbrdf-capture/1`` folder
at ``path`` (:func:`.photograph.capture_to_folder`, the same writer
a rig uses), and then hands the Capture node exactly what the ``folder``
plugin reading that folder would (:class:`sbrdf_capture.folder.FolderCapture`
does the reading, with the parameters under ``read``).  The folder is the
point: it is what a real rig writes, so downstream nodes see a scan, not a
simulator's shortcut, and the folder can be read again later with
``plugin: folder``.

Poses: ``poses`` camera/light pairs on two Fibonacci spirals over the
hemisphere (:func:`.photograph.orbit_poses`, shaped by ``orbit``).
Exposures: one bracket of 1-3 times for every pose, or one bracket per pose.

Caching and the folder:

* The Capture node's cache key is its parameters (this source has no
  data of its own to fingerprint beyond a ``param_maps`` artifact), so a
  re-run with the same parameters neither renders nor reads anything.
* Rendering happens in :meth:`VirtualFolderCapture.describe`, which the
  runner calls only when the node actually runs.  Every parameter that
  shapes the images is recorded in the manifest under ``rig``
  (``source: virtual-folder``); a complete folder with the same record is
  read back without rendering, an unfinished one is resumed (the camera's
  random effects are seeded per pose, so a resumed capture equals an
  uninterrupted one).
* A folder this source wrote with other parameters is derived data: it is
  re-rendered in place (the images its manifest lists are removed,
  ``capture.json`` is rewritten and the poses are taken again).  A
  folder written by anything else (a real scan, ``gonio``, a script, or
  any folder holding files but no ``capture.json``) is never touched: the
  node fails and names it.  Only a missing folder, one holding no files,
  or one this source wrote (its ``capture.json``, recorded before any
  image) is written.
"""

from __future__ import annotations

import hashlib
import json
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sbrdf_core.contracts import optional
from sbrdf_core.errors import ParameterError
from sbrdf_core.nodes.capture import CaptureDescription

from .declarations import VIRTUAL_FOLDER
from .read_back import ReadBack

if TYPE_CHECKING:
    from sbrdf_core.registry import Registry

    from .folder import FolderCapture

log = logging.getLogger(__name__)

SOURCE = "virtual-folder"
ORBIT_KEYS = ("camera_distance_mm", "light_distance_mm", "max_camera_theta_deg", "max_light_theta_deg")
#: ``folder`` parameters this source sets itself (everything else may be given under ``read``).
READ_RESERVED = {"path", "allow_incomplete"}
def _jsonable(value: Any) -> Any:
    return json.loads(json.dumps(value, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


class VirtualFolderCapture(ReadBack):
    """Capture source: render a camera device's photographs into a capture folder, read it back (module docstring)."""

    source = SOURCE
    params = VIRTUAL_FOLDER

    def __init__(self, *, path: str, camera: dict = {"device": "virtual-camera", "params": {}},  # noqa: B006
                 poses: int = 60, orbit: dict = {}, exposures: list = [1.0], light: dict | None = None,  # noqa: B006
                 read: dict = {}, image_format: str = "png", durable: bool = True):  # noqa: B006
        self.path = Path(str(path)).expanduser()
        if not isinstance(camera, dict) or "device" not in camera or set(camera) - {"device", "params"}:
            raise ParameterError(f"{SOURCE}: camera: expected {{device: <device plugin>, params: {{...}}}}, got {camera!r}")
        if not isinstance(camera.get("params") or {}, dict):
            raise ParameterError(f"{SOURCE}: camera.params: expected a mapping, got {camera['params']!r}")
        self.camera_config: dict[str, Any] = {"device": str(camera["device"]), "params": dict(camera.get("params") or {})}
        self.n_poses = int(poses)
        unknown = sorted(set(orbit) - set(ORBIT_KEYS))
        if unknown:
            raise ParameterError(f"{SOURCE}: orbit: unknown key(s) {unknown}; accepted: {list(ORBIT_KEYS)}")
        self.orbit = {k: float(v) for k, v in orbit.items()}
        self.times = self._exposures(exposures)
        self.exposure_param = self.times[0] if all(b == self.times[0] for b in self.times) else self.times
        self.light = None if light is None else dict(light)
        self.read_config = dict(read)
        bad = sorted(READ_RESERVED & set(self.read_config))
        if bad:
            raise ParameterError(f"{SOURCE}: read: {bad} are set by the {SOURCE} source itself")
        self.image_format, self.durable = image_format, bool(durable)
        self.registry: Registry | None = None
        #: The scene-rendering camera device (``photograph``, ``sample_info``, ``camera_info``...), made in :meth:`bind`.
        self.camera: Any = None
        self.reader: FolderCapture | None = None
        self.rendered = 0  #: poses photographed by this instance (0 when the folder was already complete)
        self._ready = False

    def _exposures(self, exposures) -> list[list[float]]:
        P = self.n_poses
        if isinstance(exposures, (int, float)) and not isinstance(exposures, bool):
            exposures = [exposures]
        ok_time = lambda x: isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0  # noqa: E731
        if isinstance(exposures, list) and exposures and all(ok_time(x) for x in exposures):
            times = [[float(x) for x in exposures]] * P
        elif (isinstance(exposures, list) and len(exposures) == P
              and all(isinstance(b, list) and b and all(ok_time(x) for x in b) for b in exposures)):
            times = [[float(x) for x in b] for b in exposures]
        else:
            raise ParameterError(f"{SOURCE}: exposures: expected one bracket of positive times for every pose, e.g. "
                                 f"[0.25, 1.0], or one bracket per pose ({P} lists), got {exposures!r}")
        for i, bracket in enumerate(times):
            if not 1 <= len(bracket) <= 3:
                raise ParameterError(f"{SOURCE}: exposures: pose {i} has bracket {bracket}; a bracket is 1 to 3 times")
        return times

    # -- plugins ------------------------------------------------------------------------------------

    def bind(self, registry) -> None:
        """Create the camera device and the folder reader (cheap: nothing is rendered or read here)."""
        self.registry = registry
        self.camera = registry.create("device", self.camera_config["device"], self.camera_config["params"])
        if optional(self.camera, "bind", "device") is not None:
            self.camera.bind(registry)
        self.reader = registry.create("capture", "folder", {**self.read_config, "path": str(self.path)})

    def fingerprint(self) -> str:
        """The parameters are the node's cache key already; only a ``param_maps`` artifact adds data."""
        maps = self.camera_config["params"].get("param_maps")
        if not maps:
            return SOURCE
        h = hashlib.sha256(SOURCE.encode())
        for name in ("zarr.json", ".zattrs"):
            f = Path(str(maps)).expanduser() / name
            if f.is_file():
                h.update(f.read_bytes())
        return h.hexdigest()

    def __dask_tokenize__(self):
        return ("sbrdf-virtual-folder", str(self.path), id(self))

    def __getstate__(self):
        # Workers only read the finished folder; the camera (rays, maps) stays in the client.
        state = dict(self.__dict__)
        state["camera"] = None
        state["registry"] = None
        return state

    # -- the capture ----------------------------------------------------------------------------------

    def planned(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[list[float]]]:
        """``(light_pos (P, 3), R (P, 3, 3), t (P, 3), exposure brackets)`` of the capture."""
        from .photograph import orbit_poses

        light, R, t = orbit_poses(self.n_poses, **self.orbit)
        return light, R, t, self.times

    def rig_record(self) -> dict:
        """What the manifest records under ``rig``: every parameter that shapes the images."""
        return _jsonable({"source": SOURCE, "camera": self.camera_config, "poses": self.n_poses, "orbit": self.orbit,
                          "exposures": self.exposure_param, "light": self.light})

    def _header(self) -> dict:
        cam = self.camera
        header = {"format": "sbrdf-capture/1", "sample": cam.sample_info(), "camera": cam.camera_info(),
                  "light": self.light if self.light is not None else cam.light_info()}
        if hasattr(cam, "simulation_info"):
            header["simulation"] = cam.simulation_info()
        header["rig"] = self.rig_record()
        return _jsonable(header)

    def ensure_folder(self) -> None:
        """Make ``path`` hold this capture, complete: reuse, resume or (re-)render it."""
        if self._ready:
            return
        if self.camera is None:
            from sbrdf_core.registry import default_registry

            self.bind(default_registry())
        from sbrdf_lib.capture_folder import MANIFEST, CaptureFolderError, load_manifest, parse_manifest

        from .photograph import capture_to_folder

        header = self._header()
        expected = parse_manifest({**header, "complete": False, "poses": []}, f"{self.path} ({SOURCE} header)").header_json()
        overwrite = False
        manifest = self.path / MANIFEST
        if not manifest.exists() and not manifest.is_symlink():
            self._refuse_foreign_folder()
        if manifest.exists():
            old = load_manifest(self.path)
            rig = old.extra.get("rig")
            if not (isinstance(rig, dict) and rig.get("source") == SOURCE):
                raise CaptureFolderError(
                    f"{manifest}: holds a capture that the {SOURCE} source did not write "
                    f"({'complete' if old.complete else 'unfinished'}; rig source {rig.get('source') if isinstance(rig, dict) else None!r}); "
                    f"it is left alone - give {SOURCE} another path, or read that folder with plugin: folder")
            same = old.header_json() == expected
            if same and old.complete and sorted(p.id for p in old.poses) == list(range(self.n_poses)):
                log.info("%s: %s already holds this capture (%d poses); nothing rendered", SOURCE, self.path, self.n_poses)
                self._ready = True
                return
            if not same:
                log.warning("%s: %s holds a capture of this source with other parameters; re-rendering it", SOURCE,
                            self.path)
                overwrite = True
            elif old.complete:  # same header, other pose ids: not something this source writes; redo it
                overwrite = True
        light, R, t, times = self.planned()
        if overwrite:
            from sbrdf_lib.capture_folder import CaptureFolderWriter, read_journal, resolve_image

            # Drop the images the old capture recorded (this source wrote them), so none outlives its manifest.
            for pose in old.poses + read_journal(self.path):
                for e in pose.exposures:
                    resolve_image(self.path, e, f"pose {pose.id}").unlink(missing_ok=True)
            h = header
            CaptureFolderWriter(self.path, h["sample"], h["camera"], h["light"], image_format=self.image_format,
                                durable=self.durable, overwrite=True,
                                extra={k: v for k, v in h.items() if k not in ("format", "sample", "camera", "light")})

        bar = None
        if sys.stderr.isatty():  # rendering comes before the node's chunk bar: show it on a terminal
            from tqdm import tqdm

            bar = tqdm(total=self.n_poses, desc=f"{'(render)':<12}", unit="pose", file=sys.stderr, leave=False)

        def progress(done: int, total: int) -> None:
            self.rendered += 1
            if bar is not None:
                bar.n = done
                bar.refresh()
            if done == total or done % 10 == 0:
                log.info("%s: %d/%d poses in %s", SOURCE, done, total, self.path)

        try:
            capture_to_folder(self.camera, self.path, light, R, t, times, light=header["light"],
                              image_format=self.image_format, durable=self.durable, progress=progress,
                              extra={k: v for k, v in header.items() if k not in ("format", "sample", "camera", "light")})
        finally:
            if bar is not None:
                bar.close()
        self._ready = True

    def _refuse_foreign_folder(self) -> None:
        from sbrdf_lib.capture_folder import refuse_foreign_folder

        refuse_foreign_folder(self.path, SOURCE)  # before rendering: the writer would refuse it only after

    # -- capture source protocol ------------------------------------------------------------------

    def describe(self) -> CaptureDescription:
        """Render (or reuse) the folder, then describe it exactly as ``folder`` does."""
        self.ensure_folder()
        reader = self._folder_reader()
        reader.manifest = None  # (re)read the finished folder as the folder plugin would
        return reader.describe()

    def read_pose(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        if not self._ready:
            self.describe()
        return self._folder_reader().read_pose(int(index))
