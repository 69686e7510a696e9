"""folder: read an ``sbrdf-capture/1`` capture folder into the pipeline.

This is how real scans (and other simulators) enter: whatever wrote the
folder, the Capture node sees linear HDR radiance per pose.  The whole
manifest and every image header are validated in :meth:`FolderCapture.describe`,
before the node writes anything, so a broken folder fails with a message
naming the file, the pose and the field, and leaves no partial artifact.

Per pose (:meth:`FolderCapture.read_pose`, one pose in memory at a time):
decode each exposure (EXR through :mod:`sbrdf_core.io.images`, 8/16-bit PNG
and TIFF through cv2), linearise it with the response curve, subtract the
dark frame, and merge the bracket (:func:`sbrdf_capture.hdr.merge_exposures`);
saturated and under-exposed pixels are marked invalid.  An optional 3×3
colour matrix takes camera RGB to the working space.

Calibration captures (the ``DarkFrame`` and ``FlatField`` nodes, wired into
the Capture node's ``dark`` and ``flat`` inputs) reach the reader through
:meth:`FolderCapture.calibrate`: every exposure's linear signal becomes
``(S - offset - rate · t) / flat`` (:func:`sbrdf_lib.calibration.correct`)
before the merge, and pixels the flat cannot correct are invalid.  The
``dark_frame`` parameter (a lens-capped image inside the folder, scaled by
exposure time) is the older, simpler form; a reader takes one or the other.

Response curve: the manifest's, else ``"linear"`` for float images, else it
is recovered from the brackets (McAllister's cubic by default, or Debevec's)
once, at describe time, from a sample of pixels of up to ``response_poses``
bracketed poses.

Negative radiance (physically impossible; docs/capture-folders.md, "What is
refused"): after the merge, before the colour matrix, a pixel with a channel
below ``-negative_tolerance x full scale`` is marked invalid and counted
(:attr:`FolderCapture.negative_pixels`; a debug line per pose on the
``sbrdf.capture.folder`` logger, and one warning per node from
:meth:`FolderCapture.read_report`, which the Capture node logs when every pose
is written).  Full scale is the radiance that fills
the pose's longest exposure (normalised code 1 through the response, or
``camera.white_level``; for float images without a white level, the pose's
brightest value).  Smaller negatives are sensor noise around zero (e.g.
after dark-frame subtraction) and stay as measured, unclamped, so averages
stay unbiased.  A pose where more than ``negative_max_fraction`` of the pixels
are negative beyond the tolerance (every pixel, in a sign-flipped image), or
more than that fraction of the pixels that stand out of the noise (a
sign-flipped image whose background is dark: :meth:`FolderCapture._significant`),
is not noise but a broken image or calibration: a :class:`CaptureFolderError`
naming the pose and its files.
"""

from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path
from struct import error as struct_error

import numpy as np

from sbrdf_core.types import CaptureDescription
from sbrdf_lib.calibration import correct, flat_usable
from sbrdf_lib.capture_folder import (
    MANIFEST,
    CaptureFolderError,
    Exposure,
    Manifest,
    PoseRecord,
    image_size,
    inside_folder,
    manifest_sections,
    read_image,
    resolve_image,
    validate_folder,
)
from sbrdf_lib.response import ResponseCurve, ResponseError

from .declarations import FOLDER
from .hdr import merge_exposures, subtract_dark
from .response import bracket_samples, cubic_curve, recover_cubic_loglog, recover_debevec

#: Codes below this (normalised) are left out of the response fit: dark pixels are
#: noise-dominated and bias the log-log fit.  Merging still uses them down to ``underexposure``.
RECOVERY_LOW = 0.1

log = logging.getLogger("sbrdf.capture.folder")


class FolderCapture:
    """Capture source reading an ``sbrdf-capture/1`` folder (see module docstring)."""

    params = FOLDER

    def __init__(self, *, path: str, response: str = "auto", response_method: str = "cubic", response_poses: int = 8,
                 saturation: float = 0.98, underexposure: float = 0.02, dark_frame: str | None = None,
                 dark_time_s: float | None = None, colour_matrix: list | None = None, allow_incomplete: bool = False,
                 negative_tolerance: float = 0.01, negative_max_fraction: float = 0.5):
        self.path = Path(os.path.expanduser(str(path)))
        self.response_mode, self.response_method, self.response_poses = response, response_method, response_poses
        self.saturation, self.underexposure = saturation, underexposure
        self.dark_frame_name, self.dark_time_s = dark_frame, dark_time_s
        self.colour_matrix = None if colour_matrix is None else np.asarray(colour_matrix, np.float64).reshape(3, 3)
        self.allow_incomplete = allow_incomplete
        self.negative_tolerance = float(negative_tolerance)
        self.negative_max_fraction = float(negative_max_fraction)
        #: Pose id -> pixels made invalid by negative radiance beyond the tolerance (poses read in this process).
        self.negative_pixels: dict[int, int] = {}
        #: Pose id -> (where, pixels, files) of those poses, for :meth:`read_report`.
        self._negative_detail: dict[int, tuple[str, int, str]] = {}
        self.manifest: Manifest | None = None
        self.curve: ResponseCurve | None = None
        self.linear = False
        self._dark: np.ndarray | None = None
        #: ``(offset, rate, flat)`` from calibration captures (:meth:`calibrate`), each ``(H, W, 3)`` or ``None``.
        self._calibration: tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None] = (None, None, None)

    # -- protocol ------------------------------------------------------------------

    def fingerprint(self) -> str:
        """Changes when any file the capture reads changes: ``capture.json`` and the journal (their bytes), and
        (size, mtime) of every image the manifest or journal names, wherever in the folder it lies, of every file
        below ``images/`` (subfolders included) and of the dark frame."""
        import json

        from sbrdf_lib.capture_folder import JOURNAL

        h = hashlib.sha256()
        try:
            manifest = inside_folder(self.path, MANIFEST, "manifest capture.json")
            text = manifest.read_bytes()
            journal = inside_folder(self.path, JOURNAL, "journal capture.journal")
            extra = journal.read_bytes() if journal.is_file() else b""
        except CaptureFolderError:
            return "outside"  # never read a file outside the folder; describe() reports it
        except OSError:
            return "missing"
        h.update(text)
        h.update(b"\0journal\0" + extra)
        names: set[str] = set()
        records: list = []
        try:
            doc = json.loads(text)
            records = list(doc.get("poses") or []) if isinstance(doc, dict) else []
        except ValueError:
            pass  # describe() reports it
        for line in extra.splitlines():
            try:
                records.append(json.loads(line))
            except ValueError:
                pass  # a torn last line: the reader drops it too
        for pose in records:
            for e in (pose.get("exposures") or []) if isinstance(pose, dict) else []:
                if isinstance(e, dict) and isinstance(e.get("file"), str):
                    names.add(e["file"])
        images = self.path / "images"
        if images.is_dir():
            for root, dirs, files in os.walk(images):
                dirs.sort()
                names.update(os.path.relpath(os.path.join(root, f), self.path) for f in files)
        if self.dark_frame_name:
            names.add(self.dark_frame_name)
        for name in sorted(names):
            try:
                st = os.stat(self.path / name)
                h.update(f"{name}:{st.st_size}:{st.st_mtime_ns}\n".encode())
            except (OSError, ValueError):
                h.update(f"{name}:missing\n".encode())
        return h.hexdigest()

    def describe(self) -> CaptureDescription:
        m = self._open()
        poses = m.poses
        sample, camera, light = manifest_sections(m, self.linear)
        return CaptureDescription(
            height=m.camera.height, width=m.camera.width,
            light_pos=np.array([p.light_pos_mm for p in poses], np.float64),
            camera_R=np.array([p.R for p in poses], np.float64),
            camera_t=np.array([p.t for p in poses], np.float64),
            exposure_s=np.array([min(e.time_s for e in p.exposures) for p in poses], np.float64),
            sample=sample, camera=camera, light=light,
        )

    def read_pose(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        m = self._open()
        pose = m.poses[index]
        return self.read_record(pose, f"poses[{index}] (id {pose.id})")

    def calibrate(self, *, dark_offset: np.ndarray | None = None, dark_rate: np.ndarray | None = None,
                  flat: np.ndarray | None = None) -> None:
        """Correct every exposure with a dark model and a normalised flat field (module docstring).

        Each array is ``(H, W, 3)`` in linear signal units (the camera's codes
        through the same response as the photographs): what the ``DarkFrame``
        and ``FlatField`` nodes store.  The Capture node calls this before
        :meth:`describe` when its ``dark``/``flat`` inputs are wired.
        """
        if self.dark_frame_name and (dark_offset is not None or dark_rate is not None):
            raise CaptureFolderError(f"{self.path / MANIFEST}: both a dark_frame ({self.dark_frame_name}) and a DarkFrame "
                                     "input were given; use one of them")
        arrays = [None if a is None else np.asarray(a, np.float32) for a in (dark_offset, dark_rate, flat)]
        shapes = {a.shape for a in arrays if a is not None}
        if len(shapes) > 1 or any(len(s) != 3 or s[2] != 3 for s in shapes):
            raise CaptureFolderError(f"{self.path / MANIFEST}: calibration arrays must share one (H, W, 3) shape, got "
                                     f"{sorted(shapes)}")
        self._calibration = (arrays[0], arrays[1], arrays[2])

    def _check_calibration(self, m: Manifest) -> None:
        shapes = {a.shape[:2] for a in self._calibration if a is not None}
        if shapes and shapes != {(m.camera.height, m.camera.width)}:
            (h, w), = shapes
            raise CaptureFolderError(f"{self.path / MANIFEST}: the calibration captures (dark frame, flat field) are "
                                     f"{w}x{h} pixels but the camera is {m.camera.width}x{m.camera.height}; take them "
                                     "with the camera and region of interest of the capture")

    # -- shared with rigs that write a folder while they read it (the ``gonio`` source) -------

    def attach(self, manifest: Manifest) -> None:
        """Read through ``manifest`` instead of loading ``capture.json``.

        A rig capture source (``gonio``) writes the folder while the Capture
        node reads it: it hands over its writer's header (and poses) so each
        pose can be read back as soon as it is on disk, through exactly the
        response / dark-frame / merge path below, without re-validating the
        whole folder per pose.  The response curve is chosen here, so a
        manifest without one needs every bracketed pose (recovery samples them).
        """
        self.linear, self.curve, self._dark = False, None, None
        self._choose_response(manifest)
        self._check_calibration(manifest)
        self.manifest = manifest
        if self.dark_frame_name:
            self._load_dark(manifest, self.dark_frame_name)

    def read_record(self, pose: PoseRecord, where: str) -> tuple[np.ndarray, np.ndarray]:
        """One pose's linear HDR radiance and validity: decode, linearise, subtract dark, merge, colour."""
        m = self.manifest
        if m is None:
            raise CaptureFolderError(f"{self.path / MANIFEST}: read_record before the folder was opened or attached")
        signals, levels, times = [], [], []
        float_pose = False  # local: dask threads read poses of one capture concurrently
        offset, rate, flat = self._calibration
        for k, e in enumerate(pose.exposures):
            at = f"{where}.exposures[{k}]"
            img = self._read(resolve_image(self.path, e, at + ".file"), at, m)
            signal, level = self._linearize(img, at)
            float_pose = float_pose or img.dtype.kind == "f"
            signal = subtract_dark(signal, self._dark, self.dark_time_s or 1.0, e.time_s)
            if offset is not None or rate is not None:
                if self.linear and img.dtype.kind == "u":
                    # Linear codes: judge under-exposure above the dark signal, not above zero.
                    level = correct(level, e.time_s, offset, rate)
                signal = correct(signal, e.time_s, offset, rate)
            signals.append(signal if flat is None else correct(signal, e.time_s, flat=flat))
            levels.append(level)
            times.append(e.time_s)
        radiance, valid = merge_exposures(signals, levels, times, self.saturation, self.underexposure)
        if flat is not None:
            valid = valid & flat_usable(flat)
        valid = self._negative_radiance(radiance, valid, pose, where, max(times), float_pose)
        if self.colour_matrix is not None:
            from .colour import apply_matrix

            radiance = apply_matrix(radiance, self.colour_matrix)
        return radiance, valid

    def full_scale(self, radiance: np.ndarray, longest_s: float, float_pose: bool) -> float:
        """The radiance that fills the longest exposure (see the module docstring); ``float_pose``: the pose's
        images are floating point (then the camera's white level, or the pose's own largest value)."""
        m = self.manifest
        if float_pose:
            if m is not None and m.camera.white_level is not None:
                level = float(m.camera.white_level)
            else:
                finite = np.abs(radiance[np.isfinite(radiance)])
                return float(finite.max()) if finite.size else 0.0
        elif self.curve is not None and not self.linear:
            level = float(self.curve.table[-1].max())
        else:
            level = 1.0  # linear integer codes, normalised
        return level / float(longest_s)

    def _negative_radiance(self, radiance: np.ndarray, valid: np.ndarray, pose: PoseRecord, where: str,
                           longest_s: float, float_pose: bool) -> np.ndarray:
        """Apply the negative-radiance rule: invalidate and count, or refuse the pose."""
        below = np.where(np.isfinite(radiance), radiance, 0.0).min(axis=-1)
        if not (below < 0).any():
            return valid
        tolerance = self.negative_tolerance * self.full_scale(radiance, longest_s, float_pose)
        negative = below < -tolerance
        n = int(negative.sum())
        if n == 0:
            return valid
        total = int(negative.size)
        files = ", ".join(e.file for e in pose.exposures)
        significant = self._significant(radiance, below, tolerance)
        if n == total or n > self.negative_max_fraction * total or significant:
            how = (f"{n} of {total} pixels ({100.0 * n / total:.1f}%) have negative radiance beyond the noise "
                   f"tolerance {tolerance:.3g}")
            if significant and not (n == total or n > self.negative_max_fraction * total):
                neg, sig, floor = significant
                how = (f"{neg} of the {sig} pixels above the noise floor {floor:.3g} ({100.0 * neg / sig:.1f}%; the "
                       f"rest of the image is dark) have negative radiance")
            raise CaptureFolderError(
                f"{self.path / MANIFEST}: {where}: {how} (min {float(below.min()):.3g}) in {files}: "
                f"radiance cannot be negative, so the image or its calibration is broken (a dark frame brighter than "
                f"the image, a wrong dark_time_s, a sign error in whatever wrote it); at most "
                f"{self.negative_max_fraction:g} of a pose, or of its pixels above the noise, may be negative "
                f"(negative_max_fraction)")
        if pose.id in self.negative_pixels:  # the same pose read again (Register reads a pose more than once)
            return valid & ~negative
        self.negative_pixels[pose.id] = n
        self._negative_detail[pose.id] = (where, total, files)
        # One line per pose only at debug level: a scan with many such poses would bury the run's output;
        # read_report() sums them up for the node.
        log.debug("%s: %s: %d of %d pixels have negative radiance below -%.3g (the noise tolerance, "
                  "negative_tolerance %g of full scale) in %s; marked invalid", self.path, where, n, total, tolerance,
                  self.negative_tolerance, files)
        return valid & ~negative

    def read_report(self) -> tuple[str, dict] | None:
        """What reading the poses found, for the Capture node: ``(one line, attributes)`` or ``None``.

        The line says how many of the poses read in this process had pixels with negative radiance beyond the
        noise tolerance (made invalid) and which pose had the most; the attributes hold the count per pose id.
        """
        counts = dict(self.negative_pixels)
        if not counts:
            return None
        worst = max(counts, key=lambda i: (counts[i], -i))
        where, total, files = self._negative_detail.get(worst, (f"pose id {worst}", 0, "?"))
        share = f" ({100.0 * counts[worst] / total:.2g}%)" if total else ""
        n_poses = len(self.manifest.poses) if self.manifest is not None else len(counts)
        line = (f"{self.path}: {len(counts)} of {n_poses} poses have pixels with negative radiance beyond the noise "
                f"tolerance (negative_tolerance {self.negative_tolerance:g} of full scale), marked invalid; worst "
                f"{where}: {counts[worst]} pixels{share} in {files} (-vv lists every pose)")
        return line, {"negative_radiance_pixels": {str(i): counts[i] for i in sorted(counts)}}

    def _significant(self, radiance: np.ndarray, below: np.ndarray, tolerance: float) -> tuple[int, int, float] | None:
        """``(negative, significant, floor)`` when more than ``negative_max_fraction`` of the pixels that stand out
        of the noise are negative (a sign-flipped image whose background is dark), else ``None``.

        A pixel stands out when a channel's magnitude exceeds the noise floor: the tolerance, or five robust
        standard deviations (1.4826 MAD, over a subsample) of the pose's values, whichever is larger, so the
        symmetric noise of a dark pose never looks like a majority.  At least 0.1 % of the pixels (and 16) must
        stand out, so a few hot pixels on a black pose do not decide.
        """
        finite = np.where(np.isfinite(radiance), radiance, 0.0)
        flat = finite.reshape(-1)
        sample = flat[:: max(1, flat.size // 1_000_000)]
        mad = float(np.median(np.abs(sample - np.median(sample))))
        floor = max(float(tolerance), 5.0 * 1.4826 * mad)
        neg = below < -floor
        pos = (finite.max(axis=-1) > floor) & ~neg
        n_neg, n_sig = int(neg.sum()), int(neg.sum() + pos.sum())
        if n_sig < max(16, below.size // 1000) or n_neg <= self.negative_max_fraction * n_sig:
            return None
        return n_neg, n_sig, floor

    # -- internals -------------------------------------------------------------------------

    def _open(self) -> Manifest:
        if self.manifest is None:
            self.attach(validate_folder(self.path, allow_incomplete=self.allow_incomplete))
        assert self.manifest is not None, "attach() sets the manifest"
        return self.manifest

    def _read(self, path: Path, where: str, m: Manifest) -> np.ndarray:
        """Decode one image once its header says it has the camera's size: a file whose header claims more
        pixels (a decompression bomb, a stray photograph) fails at once, before a byte of it is inflated."""
        try:
            width, height = image_size(path)
        except FileNotFoundError:
            raise CaptureFolderError(f"{path}: image is missing ({where})") from None
        except (OSError, ValueError, struct_error) as e:
            raise CaptureFolderError(f"{path}: unreadable image ({where}): {e}") from None
        if (width, height) != (m.camera.width, m.camera.height):
            raise CaptureFolderError(f"{path}: the image header says {width}x{height} pixels but the camera is "
                                     f"{m.camera.width}x{m.camera.height} ({where}); not decoded")
        img = read_image(path, where)
        if img.shape[:2] != (m.camera.height, m.camera.width):  # a header that lied
            raise CaptureFolderError(f"{path}: image is {img.shape[1]}x{img.shape[0]} but the camera is "
                                     f"{m.camera.width}x{m.camera.height} ({where})")
        return img

    def _linearize(self, img: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
        """Pixels -> (linear signal, normalised level judged for saturation)."""
        if img.dtype.kind == "f":
            signal = img.astype(np.float32)
            white = self.manifest.camera.white_level if self.manifest else None
            level = np.full(signal.shape, 0.5, np.float32) if white is None else signal / np.float32(white)
            return signal, level
        if self.linear:
            top = float(np.iinfo(img.dtype).max)
            return img.astype(np.float32) / np.float32(top), img.astype(np.float32) / np.float32(top)
        curve = self.curve
        assert curve is not None, "attach() chose the response: linear, or this curve"
        if img.dtype.itemsize * 8 != curve.bits:
            raise CaptureFolderError(f"{self.path / MANIFEST}: {where}: a {img.dtype.itemsize * 8}-bit image but the "
                                     f"response curve has {curve.table.shape[0]} entries ({curve.bits}-bit)")
        return curve.linearize(img), img.astype(np.float32) / np.float32(curve.max_code)

    def _choose_response(self, m: Manifest) -> None:
        mode = self.response_mode
        given = m.camera.response
        if mode == "linear" or (mode in ("auto", "manifest") and given == "linear"):
            self.linear = True
            return
        if mode in ("auto", "manifest") and isinstance(given, dict):
            self.curve = ResponseCurve.from_manifest(given)
            return
        if mode == "manifest":
            raise CaptureFolderError(f"{self.path / MANIFEST}: camera.response: absent, but the folder plugin was told "
                                     "response: manifest")
        # Recover from brackets ("auto" without a curve, or "recover").
        first = self._read(resolve_image(self.path, m.poses[0].exposures[0], "poses[0].exposures[0].file"),
                           "poses[0].exposures[0]", m)
        if first.dtype.kind == "f":
            self.linear = True  # float images are linear by definition
            return
        bracketed = [p for p in m.poses if len(p.exposures) >= 2]
        if not bracketed:
            raise CaptureFolderError(f"{self.path / MANIFEST}: camera.response is absent and no pose has an exposure "
                                     "bracket (two or more exposures) to recover it from; add the response table or "
                                     "pass response: linear")
        # Brackets may differ per pose in their times and their length (the exposure planner's 1-3 times per pose):
        # every sample carries its own exposure time, which both recovery methods accept.
        step = max(1, len(bracketed) // self.response_poses)
        chosen = bracketed[::step][: self.response_poses]
        max_code = int(np.iinfo(first.dtype).max)
        brackets, times = [], []
        for p in chosen:
            imgs = [self._read(resolve_image(self.path, e, f"pose {p.id}"), f"pose {p.id}", m) for e in p.exposures]
            order = np.argsort([e.time_s for e in p.exposures])
            brackets.append([imgs[i] for i in order])
            times.append([p.exposures[i].time_s for i in order])
        try:
            samples, sample_times = bracket_samples(brackets, times, max_code=max_code,
                                                    low=self.underexposure, high=self.saturation)
            if self.response_method == "debevec":
                self.curve = recover_debevec(samples, sample_times)
            else:
                low = max(self.underexposure, RECOVERY_LOW)
                coef = recover_cubic_loglog(samples, sample_times, max_code, low, self.saturation)
                self.curve = cubic_curve(coef, 8 if max_code == 255 else 16, low)
        except ResponseError as e:
            raise CaptureFolderError(
                f"{self.path / MANIFEST}: camera.response is absent, so the response curve was to be recovered from "
                f"the exposure brackets ({self.response_method} method, {len(chosen)} of {len(bracketed)} bracketed "
                f"poses), and that failed: {e}.  Record camera.response in the manifest, pass response: linear for "
                "linear images, or try the other response_method") from None

    def _load_dark(self, m: Manifest, name: str) -> None:
        e = Exposure(name, self.dark_time_s or 1.0)
        path = resolve_image(self.path, e, "dark_frame")
        img = self._read(path, "dark_frame", m)
        self.manifest = m
        self._dark = self._linearize(img, "dark_frame")[0]
