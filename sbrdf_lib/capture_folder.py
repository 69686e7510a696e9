"""The ``sbrdf-capture/1`` capture folder: manifest dataclasses, validation, and a crash-safe writer.

A capture folder is how scans enter the pipeline from any rig (DESIGN.md,
"Capture folder"): ``capture.json`` plus ``images/``.  This module is the one
place that knows the format, so the writers (the ``gonio`` rig, the virtual
camera, third-party rigs) and the reader (the ``folder`` capture plugin) cannot
drift apart; it sits in the library layer because all of them use it.

Why a journal: a capture takes hours on a real gonioreflectometer and can be
killed at any moment.  The writer therefore

- writes every image to a temporary name, flushes it, and renames it into
  place (a rename is atomic on POSIX), so an image file is either absent or
  complete;
- records a pose only *after* all its images are on disk, by appending one
  JSON line to ``capture.journal`` and flushing it; a torn last line (killed
  mid-write) is ignored;
- keeps ``capture.json`` at ``"complete": false`` until :meth:`CaptureFolderWriter.finish`
  atomically rewrites it with every pose and ``"complete": true``.

A killed capture thus resumes from the last completed pose (images of a
half-written pose are simply written again, under the same names), and a
folder never looks complete when it is not.  Folders written by other tools
carry no ``complete`` key; those are taken as complete.

Validation (:func:`load_manifest`, :func:`validate_folder`) raises
:class:`CaptureFolderError` naming the file and the JSON path of the field,
e.g. ``capture.json: poses[3] (id 3).camera.R: not orthonormal``.

Confinement: everything read or written is inside the folder.  Image paths
must be relative and resolve inside it (links included); ``capture.json`` and
``capture.journal`` themselves must be regular files inside it - a link to a
file elsewhere is refused (:func:`inside_folder`), so a folder can neither
make the reader trust a manifest from elsewhere nor make the writer append
to or replace a file outside.

Physically impossible input is refused (docs/capture-folders.md, "What is
refused"): a light at the origin or at/below the sample plane (``z <= 0``,
where it cannot light the surface) is an error naming the pose and the file.
Negative radiance in the images is handled by the reader
(the ``folder`` capture plugin).  :func:`read_image` decodes a stored image and
:func:`manifest_sections` gives a manifest's CaptureSet attributes, for every
source that reads a folder.
"""

from __future__ import annotations

import json
import logging
import math
import os
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from sbrdf_core.errors import ArtifactError

__all__ = ["FORMAT", "IMAGE_DIR", "IMAGE_SUFFIXES", "JOURNAL", "MANIFEST", "ORTHONORMAL_TOLERANCE", "CameraInfo",
           "CaptureFolderError", "CaptureFolderWriter", "Exposure", "Fiducials", "LightInfo", "Manifest", "Marker",
           "PoseRecord", "SampleInfo", "aruco_dictionaries", "check_relative_path", "encode_image", "image_size",
           "inside_folder", "load_manifest", "manifest_sections", "parse_manifest", "parse_pose", "parse_response",
           "read_image", "read_journal", "resolve_image", "validate_folder"]

logger = logging.getLogger(__name__)

FORMAT = "sbrdf-capture/1"
MANIFEST = "capture.json"
JOURNAL = "capture.journal"
IMAGE_DIR = "images"
IMAGE_SUFFIXES = (".exr", ".png", ".tif", ".tiff")
ORTHONORMAL_TOLERANCE = 1e-4


class CaptureFolderError(ArtifactError):
    """A capture folder is malformed, incomplete or inconsistent."""


def inside_folder(folder: str | os.PathLike, name: str, what: str) -> Path:
    """``folder / name``, refused if it (through any link) resolves outside the folder.

    A missing file is fine (the caller reports it); a link pointing outside,
    even a dangling one, is a :class:`CaptureFolderError`.
    """
    folder = Path(folder)
    path = folder / name
    root = folder.resolve()
    target = path.resolve()
    if target.parent != root and root not in target.parents:
        link = f" is a link to {os.readlink(path)!r} and" if path.is_symlink() else ""
        raise CaptureFolderError(f"{path}: the {what}{link} resolves to {target}, outside the capture folder {root}; "
                                 f"the {what} must be a file inside the folder (copy it in instead of linking)")
    return path


def aruco_dictionaries() -> list[str]:
    """Names of the fiducial dictionaries cv2.aruco knows (``DICT_4X4_50`` ...)."""
    import cv2

    return sorted(name for name in dir(cv2.aruco) if name.startswith("DICT_"))


# ---------------------------------------------------------------------------
# manifest dataclasses
# ---------------------------------------------------------------------------


@dataclass
class Marker:
    id: int
    corners_mm: list[list[float]]  # 4 x [x, y], OpenCV corner order, sample frame z = 0


@dataclass
class Fiducials:
    dictionary: str
    markers: list[Marker] = field(default_factory=list)


@dataclass
class SampleInfo:
    size_mm: list[float]
    fiducials: Fiducials | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class CameraInfo:
    """Intrinsics and radiometry of the camera.

    ``response`` is ``"linear"``, ``{"type": "table", "values": [...]}`` (pixel
    code -> relative radiance) or ``None`` (unknown: recover from brackets).
    ``white_level`` (extension) is the linear signal at which a float image
    saturates; ``None`` means it does not.
    """

    width: int
    height: int
    K: list[list[float]]
    dist: list[float]
    response: Any = None
    white_level: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class LightInfo:
    type: str = "point"
    intensity: float = 1.0
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class Exposure:
    file: str  # relative to the folder, forward slashes
    time_s: float


@dataclass
class PoseRecord:
    id: int
    light_pos_mm: list[float]
    R: list[list[float]]
    t: list[float]
    exposures: list[Exposure]
    extra: dict[str, Any] = field(default_factory=dict)  # e.g. "simulation": true pose of a simulator

    def to_json(self) -> dict:
        out = {"id": self.id, "light_pos_mm": list(self.light_pos_mm),
               "camera": {"R": [list(r) for r in self.R], "t": list(self.t)},
               "exposures": [{"file": e.file, "time_s": e.time_s} for e in self.exposures]}
        out.update(self.extra)
        return out


@dataclass
class Manifest:
    sample: SampleInfo
    camera: CameraInfo
    light: LightInfo
    poses: list[PoseRecord] = field(default_factory=list)
    complete: bool = True
    extra: dict[str, Any] = field(default_factory=dict)

    def header_json(self) -> dict:
        """Everything but the poses (what a resumed writer must agree with)."""
        sample: dict[str, Any] = {"size_mm": list(self.sample.size_mm), "fiducials": None}
        if self.sample.fiducials is not None:
            sample["fiducials"] = {"dictionary": self.sample.fiducials.dictionary,
                                   "markers": [{"id": m.id, "corners_mm": [list(c) for c in m.corners_mm]}
                                               for m in self.sample.fiducials.markers]}
        sample.update(self.sample.extra)
        camera = {"width": self.camera.width, "height": self.camera.height,
                  "K": [list(r) for r in self.camera.K], "dist": list(self.camera.dist)}
        if self.camera.response is not None:
            camera["response"] = self.camera.response
        if self.camera.white_level is not None:
            camera["white_level"] = self.camera.white_level
        camera.update(self.camera.extra)
        light = {"type": self.light.type, "intensity": self.light.intensity, **self.light.extra}
        return {"format": FORMAT, "sample": sample, "camera": camera, "light": light, **self.extra}

    def to_json(self) -> dict:
        return {**self.header_json(), "complete": self.complete, "poses": [p.to_json() for p in self.poses]}


# ---------------------------------------------------------------------------
# parsing and validation
# ---------------------------------------------------------------------------


class _Where:
    """Builds ``file: json.path`` prefixes for error messages."""

    def __init__(self, file: str):
        self.file = file

    def fail(self, path: str, message: str) -> NoReturn:
        raise CaptureFolderError(f"{self.file}: {path}: {message}")


def _number(w: _Where, path: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        w.fail(path, f"expected a finite number, got {value!r}")
    return float(value)


def _vector(w: _Where, path: str, value: Any, n: int) -> list[float]:
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != n:
        w.fail(path, f"expected a list of {n} numbers, got {value!r}")
    return [_number(w, f"{path}[{i}]", v) for i, v in enumerate(value)]


def _matrix(w: _Where, path: str, value: Any, rows: int, cols: int) -> list[list[float]]:
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != rows:
        w.fail(path, f"expected a {rows}x{cols} matrix (list of {rows} rows), got {value!r}")
    return [_vector(w, f"{path}[{i}]", r, cols) for i, r in enumerate(value)]


def _section(w: _Where, data: Mapping, key: str) -> Mapping:
    value = data.get(key)
    if not isinstance(value, Mapping):
        w.fail(key, f"missing or not an object (got {value!r})")
    return value


def parse_response(w: _Where, path: str, value: Any) -> Any:
    if value is None or value == "linear":
        return value
    if isinstance(value, Mapping) and value.get("type") == "table":
        values = value.get("values")
        if not isinstance(values, Sequence) or len(values) not in (256, 65536):
            w.fail(f"{path}.values", f"expected 256 or 65536 entries, got {len(values) if isinstance(values, Sequence) else values!r}")
        arr = np.asarray(values, dtype=np.float64)
        if not np.all(np.isfinite(arr)) or np.any(np.diff(arr) < 0):
            w.fail(f"{path}.values", "must be finite and non-decreasing (pixel value -> relative radiance)")
        return {"type": "table", "values": [float(v) for v in arr]}
    w.fail(path, f"expected \"linear\" or {{\"type\": \"table\", \"values\": [...]}}, got {value!r}")


def parse_manifest(data: Any, file: str = MANIFEST) -> Manifest:
    """Validate a decoded ``capture.json`` and return it as dataclasses.

    Checks structure and values only (not the image files; see :func:`validate_folder`).
    """
    w = _Where(file)
    if not isinstance(data, Mapping):
        w.fail("$", "the manifest must be a JSON object")
    fmt = data.get("format")
    if fmt != FORMAT:
        w.fail("format", f"is {fmt!r}; this reader understands {FORMAT!r}")

    s = _section(w, data, "sample")
    size = _vector(w, "sample.size_mm", s.get("size_mm"), 2)
    if min(size) <= 0:
        w.fail("sample.size_mm", f"must be positive, got {size}")
    fiducials = None
    f = s.get("fiducials")
    if f is not None:
        if not isinstance(f, Mapping):
            w.fail("sample.fiducials", f"expected an object or null, got {f!r}")
        dictionary = f.get("dictionary")
        known = aruco_dictionaries()
        if dictionary not in known:
            w.fail("sample.fiducials.dictionary", f"unknown fiducial dictionary {dictionary!r}; cv2.aruco knows {', '.join(known)}")
        markers = []
        seen: set[int] = set()
        for i, m in enumerate(f.get("markers") or []):
            p = f"sample.fiducials.markers[{i}]"
            if not isinstance(m, Mapping) or isinstance(m.get("id"), bool) or not isinstance(m.get("id"), int) or m["id"] < 0:
                w.fail(f"{p}.id", f"expected a non-negative integer id, got {m!r}")
            if m["id"] in seen:
                w.fail(f"{p}.id", f"marker id {m['id']} appears twice")
            seen.add(m["id"])
            markers.append(Marker(m["id"], _matrix(w, f"{p}.corners_mm", m.get("corners_mm"), 4, 2)))
        fiducials = Fiducials(dictionary, markers)
    sample = SampleInfo(size, fiducials, {k: v for k, v in s.items() if k not in ("size_mm", "fiducials")})

    c = _section(w, data, "camera")
    dims = {}
    for key in ("width", "height"):
        v = c.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            w.fail(f"camera.{key}", f"expected a positive integer, got {v!r}")
        dims[key] = v
    K = _matrix(w, "camera.K", c.get("K"), 3, 3)
    if K[2] != [0.0, 0.0, 1.0] or K[0][0] <= 0 or K[1][1] <= 0 or K[1][0] != 0:
        w.fail("camera.K", f"expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K}")
    dist = c.get("dist", [0, 0, 0, 0, 0])
    if not isinstance(dist, Sequence) or isinstance(dist, str) or len(dist) not in (4, 5, 8, 12, 14):
        w.fail("camera.dist", f"expected OpenCV distortion coefficients (4, 5, 8, 12 or 14 numbers), got {dist!r}")
    dist = [_number(w, f"camera.dist[{i}]", v) for i, v in enumerate(dist)]
    response = parse_response(w, "camera.response", c.get("response"))
    white = c.get("white_level")
    if white is not None and _number(w, "camera.white_level", white) <= 0:
        w.fail("camera.white_level", f"must be positive, got {white!r}")
    camera = CameraInfo(dims["width"], dims["height"], K, dist, response, None if white is None else float(white),
                        {k: v for k, v in c.items() if k not in ("width", "height", "K", "dist", "response", "white_level")})

    lt = _section(w, data, "light")
    if lt.get("type", "point") != "point":
        w.fail("light.type", f"only 'point' lights are supported, got {lt.get('type')!r}")
    intensity = _number(w, "light.intensity", lt.get("intensity", 1.0))
    if intensity <= 0:
        w.fail("light.intensity", f"must be positive, got {intensity}")
    light = LightInfo("point", intensity, {k: v for k, v in lt.items() if k not in ("type", "intensity")})

    complete = data.get("complete", True)
    if not isinstance(complete, bool):
        w.fail("complete", f"expected true or false, got {complete!r}")
    raw_poses = data.get("poses")
    if not isinstance(raw_poses, list):
        w.fail("poses", f"expected a list, got {type(raw_poses).__name__}")
    poses = []
    ids: set[int] = set()
    files: dict[str, str] = {}
    for i, p in enumerate(raw_poses):
        pose = parse_pose(w, f"poses[{i}]", p)
        if pose.id in ids:
            w.fail(f"poses[{i}].id", f"pose id {pose.id} appears twice")
        ids.add(pose.id)
        for k, e in enumerate(pose.exposures):
            where = f"poses[{i}] (id {pose.id}).exposures[{k}].file"
            if e.file in files:
                w.fail(where, f"{e.file!r} is already used by {files[e.file]}")
            files[e.file] = where
        poses.append(pose)
    extra = {k: v for k, v in data.items() if k not in ("format", "sample", "camera", "light", "poses", "complete")}
    return Manifest(sample, camera, light, poses, complete, extra)


def parse_pose(w: _Where, path: str, p: Any) -> PoseRecord:
    if not isinstance(p, Mapping):
        w.fail(path, f"expected an object, got {p!r}")
    pid = p.get("id")
    if isinstance(pid, bool) or not isinstance(pid, int) or pid < 0:
        w.fail(f"{path}.id", f"expected a non-negative integer, got {pid!r}")
    path = f"{path} (id {pid})"
    light = _vector(w, f"{path}.light_pos_mm", p.get("light_pos_mm"), 3)
    if light == [0.0, 0.0, 0.0]:
        w.fail(f"{path}.light_pos_mm", "the light is at the origin, the centre of the sample (distance 0, infinite "
                                       "irradiance); positions are mm in the sample frame")
    if light[2] <= 0:
        w.fail(f"{path}.light_pos_mm", f"z = {light[2]:g} mm: the light is at or below the sample plane (z <= 0), where "
                                       "it cannot light the surface (+z is the surface normal, z = 0 the sample plane)")
    cam = p.get("camera")
    if not isinstance(cam, Mapping):
        w.fail(f"{path}.camera", f"expected {{\"R\": ..., \"t\": ...}}, got {cam!r}")
    R = _matrix(w, f"{path}.camera.R", cam.get("R"), 3, 3)
    Ra = np.asarray(R)
    err = float(np.abs(Ra @ Ra.T - np.eye(3)).max())
    if err > ORTHONORMAL_TOLERANCE:
        w.fail(f"{path}.camera.R", f"not orthonormal (max |R Rᵀ - I| = {err:.3g} > {ORTHONORMAL_TOLERANCE})")
    if np.linalg.det(Ra) < 0:
        w.fail(f"{path}.camera.R", "is a reflection (det R = -1), not a rotation")
    t = _vector(w, f"{path}.camera.t", cam.get("t"), 3)
    exposures = p.get("exposures")
    if not isinstance(exposures, list) or not exposures:
        w.fail(f"{path}.exposures", f"expected a non-empty list, got {exposures!r}")
    out = []
    for k, e in enumerate(exposures):
        q = f"{path}.exposures[{k}]"
        if not isinstance(e, Mapping):
            w.fail(q, f"expected {{\"file\": ..., \"time_s\": ...}}, got {e!r}")
        time_s = _number(w, f"{q}.time_s", e.get("time_s"))
        if time_s <= 0:
            w.fail(f"{q}.time_s", f"exposure time must be positive, got {time_s}")
        out.append(Exposure(check_relative_path(w, f"{q}.file", e.get("file")), time_s))
    extra = {k: v for k, v in p.items() if k not in ("id", "light_pos_mm", "camera", "exposures")}
    return PoseRecord(pid, light, R, t, out, extra)


def check_relative_path(w: _Where, path: str, name: Any) -> str:
    """An image path must be relative, stay inside the folder and name a supported format."""
    if not isinstance(name, str) or not name:
        w.fail(path, f"expected a file name, got {name!r}")
    posix = name.replace("\\", "/")
    parts = posix.split("/")
    if posix.startswith("/") or (len(parts[0]) == 2 and parts[0][1] == ":") or ".." in parts:
        w.fail(path, f"{name!r} leads outside the capture folder; image paths must be relative and stay inside it")
    if not posix.lower().endswith(IMAGE_SUFFIXES):
        w.fail(path, f"{name!r}: unsupported image type; use one of {', '.join(IMAGE_SUFFIXES)}")
    return posix


def load_manifest(folder: str | os.PathLike) -> Manifest:
    """Read and validate ``<folder>/capture.json`` (structure only)."""
    folder = Path(folder)
    file = folder / MANIFEST
    if not folder.is_dir():
        raise CaptureFolderError(f"{folder}: no such capture folder")
    inside_folder(folder, MANIFEST, "manifest capture.json")
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CaptureFolderError(f"{file}: missing; a capture folder holds capture.json and images/") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise CaptureFolderError(f"{file}: not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})") from None
    return parse_manifest(data, str(file))


# ---------------------------------------------------------------------------
# image headers (size checks without decoding pixels)
# ---------------------------------------------------------------------------


def image_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` from the file header; raises ``ValueError`` if unreadable."""
    suffix = path.suffix.lower()
    if suffix == ".png":
        with open(path, "rb") as f:
            head = f.read(24)
        if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
            raise ValueError("not a PNG file (bad signature)")
        return struct.unpack(">II", head[16:24])
    if suffix == ".exr":
        import OpenEXR

        try:
            with OpenEXR.File(str(path), header_only=True) as f:
                (x0, y0), (x1, y1) = f.header()["dataWindow"]
        except Exception as e:
            raise ValueError(f"not a readable OpenEXR file ({e})") from None
        return int(x1 - x0 + 1), int(y1 - y0 + 1)
    if suffix in (".tif", ".tiff"):
        return _tiff_size(path)
    raise ValueError(f"unsupported image type {suffix!r}")


def _tiff_size(path: Path) -> tuple[int, int]:
    with open(path, "rb") as f:
        data = f.read(65536)
    if data[:4] not in (b"II*\x00", b"MM\x00*"):
        raise ValueError("not a TIFF file (bad signature)")
    e = "<" if data[:2] == b"II" else ">"
    (offset,) = struct.unpack(e + "I", data[4:8])
    if offset + 2 > len(data):
        with open(path, "rb") as f:
            f.seek(offset)
            data = data[:offset] + f.read(4096)
    (n,) = struct.unpack(e + "H", data[offset:offset + 2])
    dims = {}
    for k in range(n):
        entry = data[offset + 2 + 12 * k: offset + 14 + 12 * k]
        if len(entry) < 12:
            break
        tag, typ = struct.unpack(e + "HH", entry[:4])
        if tag in (256, 257):
            dims[tag] = struct.unpack(e + ("H" if typ == 3 else "I"), entry[8:10] if typ == 3 else entry[8:12])[0]
    if 256 not in dims or 257 not in dims:
        raise ValueError("TIFF has no ImageWidth/ImageLength tags")
    return dims[256], dims[257]


def resolve_image(folder: Path, exposure: Exposure, where: str) -> Path:
    """The absolute path of an exposure's image, refusing links that lead outside the folder."""
    root = folder.resolve()
    path = (folder / exposure.file).resolve()
    if root != path and root not in path.parents:
        raise CaptureFolderError(f"{folder / MANIFEST}: {where}: {exposure.file!r} resolves to {path}, outside the capture folder")
    return path


def validate_folder(folder: str | os.PathLike, allow_incomplete: bool = False, check_images: bool = True) -> Manifest:
    """Validate the manifest and (headers of) every image; return the manifest.

    ``check_images`` reads each image's header: it exists, is readable, and has
    the camera's width and height.  Pixels are not decoded here.
    """
    folder = Path(folder)
    manifest = load_manifest(folder)
    file = folder / MANIFEST
    if not manifest.complete and not allow_incomplete:
        journal = read_journal(folder)
        raise CaptureFolderError(
            f"{file}: complete: false - the capture was interrupted after {len(manifest.poses) + len(journal)} poses; "
            f"resume it with the writer (CaptureFolderWriter / capture_to_folder) before reading")
    if not manifest.complete:
        recorded = {p.id: p for p in manifest.poses + read_journal(folder)}
        manifest.poses = [recorded[i] for i in sorted(recorded)]
    if not manifest.poses:
        raise CaptureFolderError(f"{file}: poses: the capture has no poses")
    if check_images:
        W, H = manifest.camera.width, manifest.camera.height
        for i, pose in enumerate(manifest.poses):
            for k, e in enumerate(pose.exposures):
                where = f"poses[{i}] (id {pose.id}).exposures[{k}].file"
                path = resolve_image(folder, e, where)
                if not path.is_file():
                    raise CaptureFolderError(f"{file}: {where}: image {e.file!r} is missing ({path})")
                try:
                    w, h = image_size(path)
                except (OSError, ValueError, struct.error) as err:
                    raise CaptureFolderError(f"{path}: unreadable image ({where}): {err}") from None
                if (w, h) != (W, H):
                    raise CaptureFolderError(f"{path}: image is {w}x{h} but camera.width x camera.height is {W}x{H} ({where})")
    return manifest


# ---------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------


def _write_atomic(path: Path, data: bytes, durable: bool) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        if durable:
            f.flush()
            os.fsync(f.fileno())
    os.replace(tmp, path)


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def encode_image(image: np.ndarray, suffix: str) -> bytes:
    """Encode RGB pixels: float -> OpenEXR (ZIP), uint8/uint16 -> PNG or TIFF."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {img.shape}")
    if suffix == ".exr":
        import tempfile

        import OpenEXR

        rgb = np.ascontiguousarray(img.astype(np.float32))
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        with tempfile.TemporaryDirectory() as d:
            p = os.path.join(d, "x.exr")
            OpenEXR.File(header, {"RGB": rgb}).write(p)
            return Path(p).read_bytes()
    import cv2

    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{suffix} images must be uint8 or uint16, got {img.dtype}")
    ok, buf = cv2.imencode(suffix, np.ascontiguousarray(img[..., ::-1]))
    if not ok:
        raise ValueError(f"cv2 cannot encode a {suffix} image")
    return buf.tobytes()


def read_journal(folder: Path) -> list[PoseRecord]:
    """Poses recorded in the journal; a torn last line (a killed writer) is dropped."""
    path = inside_folder(folder, JOURNAL, "journal capture.journal")
    if not path.exists():
        return []
    w = _Where(str(path))
    out = []
    lines = path.read_bytes().split(b"\n")
    for n, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            data = json.loads(line)
        except json.JSONDecodeError:
            if n == len(lines) - 1:  # torn final line: that pose was not recorded
                break
            raise CaptureFolderError(f"{path}: line {n + 1} is corrupt (not the last line, so not a torn write)") from None
        out.append(parse_pose(w, f"line {n + 1}", data))
    return out


def refuse_foreign_folder(folder: Path, who: str) -> None:
    """Raise :class:`CaptureFolderError` unless ``folder`` is missing or holds no files.

    For a folder without a ``capture.json``: its writer records the manifest
    before any image, so such a folder was not started by a capture writer
    (empty folders are what a run killed before its manifest leaves); anything
    in it is someone's data, and the error names it.
    """
    if folder.exists() and not folder.is_dir():
        raise CaptureFolderError(f"{folder}: {who} path is a file, not a folder; it is left alone - give "
                                 f"{who} a missing or empty folder")
    if not folder.exists():
        return
    found = []
    for entry in sorted(folder.rglob("*")):
        if entry.is_symlink() or not entry.is_dir():
            found.append(str(entry.relative_to(folder)))
            if len(found) == 3:
                break
    if found:
        raise CaptureFolderError(
            f"{folder}: the folder holds files ({', '.join(found)}{', ...' if len(found) == 3 else ''}) but no "
            f"{MANIFEST} of a capture; {who} writes only into a missing or empty folder, or one it "
            f"wrote itself: it is left alone - give {who} another path")


class CaptureFolderWriter:
    """Writes an ``sbrdf-capture/1`` folder pose by pose, crash-safely and resumably.

    Parameters
    ----------
    folder
        Created if missing.  A folder holding files but no ``capture.json`` is
        refused (someone else's data).  If it holds an unfinished capture with the same
        sample, camera and light sections, the writer resumes it:
        :attr:`done_ids` lists the poses already recorded, and
        :meth:`write_pose` skips them.  A different header is an error (never
        silently mixed scans); a finished folder is refused unless ``overwrite``.
    sample, camera, light
        The manifest sections as JSON-ready dicts (DESIGN.md format), e.g.
        from a camera device's ``sample_info()`` / ``camera_info()`` and a light.
    image_format
        ``"png"`` or ``"tif"`` for uint8/uint16 images; float images are always
        written as OpenEXR.
    durable
        ``fsync`` every image and journal line (crash-safe against power loss,
        not just a killed process).  Off only for throughput measurements.
    extra
        Additional top-level manifest keys (e.g. simulation settings).
    """

    def __init__(self, folder: str | os.PathLike, sample: Mapping, camera: Mapping, light: Mapping, *,
                 image_format: str = "png", durable: bool = True, overwrite: bool = False, extra: Mapping | None = None):
        if image_format not in ("png", "tif"):
            raise CaptureFolderError(f"image_format must be 'png' or 'tif', got {image_format!r}")
        self.folder = Path(folder)
        self.image_format = image_format
        self.durable = durable
        header = {"format": FORMAT, "sample": dict(sample), "camera": dict(camera), "light": dict(light), **dict(extra or {})}
        # Validate the header exactly as a reader would (one pose-less manifest).
        self.manifest = parse_manifest({**header, "complete": False, "poses": []}, f"{self.folder / MANIFEST} (writer header)")
        self.header = self.manifest.header_json()
        self.poses: dict[int, PoseRecord] = {}
        if self.folder.is_dir():  # never append to, or replace, a file outside the folder through a link
            for name, what in ((MANIFEST, "manifest capture.json"), (JOURNAL, "journal capture.journal"),
                               (IMAGE_DIR, "image directory")):
                inside_folder(self.folder, name, what)
        existing = self.folder / MANIFEST
        if not existing.exists() and not existing.is_symlink():
            refuse_foreign_folder(self.folder, "the capture writer")
        if existing.exists():
            old = load_manifest(self.folder)
            if old.complete and not overwrite:
                raise CaptureFolderError(f"{existing}: the folder already holds a complete capture; pass overwrite=True to replace it")
            if old.header_json() != self.header and not overwrite:
                raise CaptureFolderError(f"{existing}: the unfinished capture there has a different sample/camera/light header; "
                                         "use another folder or overwrite=True")
            if overwrite:
                (self.folder / JOURNAL).unlink(missing_ok=True)
            else:
                for p in old.poses + read_journal(self.folder):
                    self.poses[p.id] = p
                self._rewrite_journal()  # drop a torn last line before appending
                logger.info("capture folder %s: resuming with %d poses recorded", self.folder, len(self.poses))
        (self.folder / IMAGE_DIR).mkdir(parents=True, exist_ok=True)
        if not existing.exists() or overwrite:
            self._write_manifest(complete=False, poses=[])

    # -- state ------------------------------------------------------------------

    @property
    def done_ids(self) -> set[int]:
        return set(self.poses)

    def image_name(self, pose_id: int, exposure_index: int, suffix: str) -> str:
        return f"{IMAGE_DIR}/p{pose_id:05d}_e{exposure_index}{suffix}"

    # -- writing ------------------------------------------------------------------

    def write_pose(self, pose_id: int, light_pos_mm, R, t, exposures: Sequence[tuple[np.ndarray, float]],
                   extra: Mapping | None = None) -> bool:
        """Write a pose's images, then record it; ``False`` if it was already recorded.

        ``exposures`` is a list of ``(image, time_s)``: float ``(H, W, 3)`` images
        become EXR, uint8/uint16 ones PNG/TIFF.  The pose is validated like a
        reader would before anything is written.
        """
        if pose_id in self.poses:
            return False
        W, H = self.manifest.camera.width, self.manifest.camera.height
        files = []
        for k, (image, _time_s) in enumerate(exposures):
            image = np.asarray(image)
            suffix = ".exr" if image.dtype.kind == "f" else f".{self.image_format}"
            files.append(self.image_name(pose_id, k, suffix))
            if image.shape != (H, W, 3):
                raise CaptureFolderError(f"{self.folder / files[-1]}: pose {pose_id} exposure {k}: image shape {image.shape} "
                                         f"does not match the camera ({H}, {W}, 3)")
        record = {"id": int(pose_id), "light_pos_mm": [float(v) for v in np.asarray(light_pos_mm).ravel()],
                  "camera": {"R": np.asarray(R, float).tolist(), "t": [float(v) for v in np.asarray(t).ravel()]},
                  "exposures": [{"file": f, "time_s": float(ts)} for f, (_, ts) in zip(files, exposures)],
                  **_jsonable(dict(extra or {}))}
        pose = parse_pose(_Where(str(self.folder / MANIFEST)), f"new pose {pose_id}", record)
        if not 1 <= len(pose.exposures) <= 3:
            raise CaptureFolderError(f"{self.folder / MANIFEST}: pose {pose_id}: expected 1 to 3 exposures, got {len(pose.exposures)}")
        for f, (image, _) in zip(files, exposures):
            _write_atomic(self.folder / f, encode_image(image, Path(f).suffix), self.durable)
        if self.durable:
            _fsync_dir(self.folder / IMAGE_DIR)
        line = json.dumps(record, separators=(",", ":")) + "\n"
        with open(self.folder / JOURNAL, "ab") as j:
            j.write(line.encode())
            j.flush()
            if self.durable:
                os.fsync(j.fileno())
        self.poses[pose.id] = pose
        logger.debug("capture folder %s: pose %d recorded (%d exposures)", self.folder, pose.id, len(files))
        return True

    def finish(self) -> Manifest:
        """Write the final ``capture.json`` (all poses by id, ``complete: true``) and drop the journal."""
        poses = [self.poses[i] for i in sorted(self.poses)]
        self._write_manifest(complete=True, poses=poses)
        (self.folder / JOURNAL).unlink(missing_ok=True)
        logger.info("capture folder %s: complete (%d poses)", self.folder, len(poses))
        return load_manifest(self.folder)

    def _write_manifest(self, complete: bool, poses: list[PoseRecord]) -> None:
        data = {**self.header, "complete": complete, "poses": [p.to_json() for p in poses]}
        text = json.dumps(data, indent=1) + "\n"
        self.folder.mkdir(parents=True, exist_ok=True)
        _write_atomic(self.folder / MANIFEST, text.encode(), self.durable)
        if self.durable:
            _fsync_dir(self.folder)

    def _rewrite_journal(self) -> None:
        lines = "".join(json.dumps(p.to_json(), separators=(",", ":")) + "\n" for p in self.poses.values())
        _write_atomic(self.folder / JOURNAL, lines.encode(), self.durable)


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


# ---------------------------------------------------------------------------
# reading (shared by every source that reads a folder)
# ---------------------------------------------------------------------------


def read_image(path: Path, where: str) -> np.ndarray:
    """Decode one image as stored: float32 (EXR) or uint8/uint16 (PNG, TIFF), ``(H, W, 3)`` RGB."""
    img: Any
    try:
        if path.suffix.lower() == ".exr":
            from sbrdf_core.io.images import read_exr

            img = read_exr(str(path))
        else:
            import cv2

            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise ValueError("cv2 cannot decode it")
            if img.ndim == 2:
                img = np.repeat(img[..., None], 3, axis=-1)
            img = img[..., [2, 1, 0]] if img.shape[-1] >= 3 else img
            if img.dtype not in (np.uint8, np.uint16):
                raise ValueError(f"unsupported sample type {img.dtype}; PNG/TIFF images must be 8- or 16-bit")
    except FileNotFoundError:
        raise CaptureFolderError(f"{path}: image is missing ({where})") from None
    except CaptureFolderError:
        raise
    except Exception as e:
        raise CaptureFolderError(f"{path}: unreadable image ({where}): {e}") from None
    return img


def manifest_sections(m: Manifest, linear: bool) -> tuple[dict, dict, dict]:
    """The CaptureSet's ``sample``, ``camera`` and ``light`` attributes for a manifest.

    Shared by every source that reads a capture folder (``folder``, ``gonio``),
    so the same scan has the same attributes whichever source produced it.
    """
    camera = {"width": m.camera.width, "height": m.camera.height, "K": [list(r) for r in m.camera.K],
              "dist": list(m.camera.dist), "model": "pinhole", "response": "linear" if linear else "table",
              **m.camera.extra}
    sample = {"size_mm": list(m.sample.size_mm),
              "fiducials": None if m.sample.fiducials is None else {
                  "dictionary": m.sample.fiducials.dictionary,
                  "markers": [{"id": k.id, "corners_mm": k.corners_mm} for k in m.sample.fiducials.markers]},
              **m.sample.extra}
    light = {"type": m.light.type, "intensity": m.light.intensity, **m.light.extra}
    return sample, camera, light
