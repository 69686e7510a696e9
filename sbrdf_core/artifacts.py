"""The typed artifacts that flow between nodes.

An artifact kind names the arrays it holds, their dimensions and meaning.  The
zarr layout (chunking, attributes, completion) is in :mod:`sbrdf_core.store`.
Dimension letters: ``P`` poses, ``H, W`` image rows/columns, ``V, U`` texel
rows/columns (v along +y, u along +x of the sample frame), ``C`` colour or
parameter channels, ``K`` texture channels.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ArraySpec:
    """One array an artifact kind holds (``name`` may contain ``/`` for sub-groups)."""

    name: str
    dims: str
    dtype: str
    doc: str
    required: bool = True
    #: A wall-clock measurement: identical runs differ in it and nothing else.
    timing: bool = False


@dataclass(frozen=True)
class ArtifactKind:
    """A kind of artifact: its name, layout version and arrays.

    The six kinds of the pipeline are declared here; plugins add theirs
    through the ``sbrdf_artifact_kinds`` hook (the registry records them in
    :data:`KINDS` when it loads, so no import has side effects).

    ``material`` makes a kind renderable: ``"package.module:function"`` of an
    adapter ``(artifact, model, params, **options) -> surface`` (the surface
    has ``radiance``, ``glsl``, ``glsl_radiance``, ``gl_uniforms`` and
    ``gl_textures``) that the renderers call for a ``Render`` input or a scene
    material of this kind (a shading map is a material).
    """

    kind: str
    version: int
    doc: str
    arrays: tuple[ArraySpec, ...] = ()
    material: str = ""

    def spec(self, name: str) -> ArraySpec | None:
        for a in self.arrays:
            if a.name == name or (a.name.endswith("/*") and name.startswith(a.name[:-1])):
                return a
        return None


CaptureSet = ArtifactKind(
    "CaptureSet",
    1,
    "Linear HDR photographs, one per pose, pose-major, with per-pose light and camera metadata. "
    "Attributes: sample (size_mm, fiducials), camera (width, height, K, dist, model), light (type, intensity).",
    (
        ArraySpec("images", "PHWC", "float32", "linear relative radiance per pixel, C = 3 (linear RGB)"),
        ArraySpec("valid", "PHW", "bool", "pixel usable: not saturated, not under-exposed, inside the frame"),
        ArraySpec("light_pos", "P3", "float64", "point-light position in the sample frame, mm (nominal)"),
        ArraySpec("camera_R", "P33", "float64", "world(sample)-to-camera rotation, OpenCV convention (nominal)"),
        ArraySpec("camera_t", "P3", "float64", "world(sample)-to-camera translation, mm (nominal)"),
        ArraySpec("exposure_s", "P", "float64", "exposure time used for the HDR image, s"),
    ),
)

RegisteredStack = ArtifactKind(
    "RegisteredStack",
    1,
    "Every accepted pose resampled onto the sample's V x U texel grid, pose-major. "
    "Attributes: texels [U, V], size_mm, light intensity, rejected poses with reasons.",
    (
        ArraySpec("radiance", "PVUC", "float32", "radiance per texel per accepted pose"),
        ArraySpec("valid", "PVU", "bool", "texel sample usable"),
        ArraySpec("pose_ids", "P", "int64", "capture pose index of each accepted pose"),
        ArraySpec("light_pos", "P3", "float64", "light position, sample frame, mm"),
        ArraySpec("camera_pos", "P3", "float64", "camera centre recovered by registration, sample frame, mm"),
        ArraySpec("homography", "P33", "float64", "sample-plane mm -> image pixel homography"),
        ArraySpec("rms_mm", "P", "float64", "registration RMS residual on the sample plane, mm"),
        ArraySpec("registration/*", "P...", "float64|int32", "the registration plugin's other per-pose measurements "
                  "(aruco: camera_R, camera_t, pixels_per_texel, pyramid_level, subsamples)", required=False),
    ),
)

SampledReflectance = ArtifactKind(
    "SampledReflectance",
    1,
    "BRDF samples f_r (sr^-1, linear RGB) per texel per pose, texel-tile-major: all poses of a tile in one chunk. "
    "omega_i, omega_r per texel follow from light_pos, camera_pos and the texel grid (sbrdf_core.geometry).",
    (
        ArraySpec("f_r", "VUPC", "float32", "sampled BRDF value, sr^-1"),
        ArraySpec("valid", "VUP", "bool", "sample usable (lit, seen, not saturated, above the horizon)"),
        ArraySpec("light_pos", "P3", "float64", "light position, sample frame, mm"),
        ArraySpec("camera_pos", "P3", "float64", "camera centre, sample frame, mm"),
        ArraySpec("truth/*", "VUC", "float32", "ground-truth parameters of a synthetic material (SampleModel)",
                  required=False),
    ),
)

ParamMaps = ArtifactKind(
    "ParamMaps",
    1,
    "Per-texel BRDF-model parameters and error maps. Attributes: model, model_config, parameters (declarations).",
    (
        ArraySpec("params/*", "VUC", "float32", "one array per model parameter"),
        ArraySpec("rms", "VU", "float32", "RMS residual of the fit over the texel's training samples, sr^-1"),
        ArraySpec("rms_holdout", "VU", "float32", "RMS error at the texel's held-out samples (never fitted), sr^-1; "
                  "NaN where none was held out", required=False),
        ArraySpec("samples", "VU", "int32", "number of valid samples the texel was fitted to"),
        ArraySpec("flags", "VU", "uint16", "why a fit is missing or doubtful: bits listed in attrs flag_bits (0 = fine)"),
        ArraySpec("restarted", "VU", "uint8", "1 where the best fit came from a later start (multi-start)",
                  required=False),
        ArraySpec("bounded_by", "VU", "uint8", "which physical bound moved a texel flagged 'constrained' (bits in "
                  "attrs bounded_by_bits: 1 peak, 2 sharpness, 4 energy)", required=False),
        ArraySpec("fit_time_s", "VU", "float32", "fitting time per texel (its tile's time shared out), s",
                  timing=True),
        ArraySpec("from_neighbour", "VU", "uint8", "1 where the texel's solution came from a neighbour's (or, with "
                  "coherence: pyramid, its parent's; with coherence: basis, its material's): one that fits its "
                  "samples better, or as well within the noise and more like its neighbourhood", required=False),
        ArraySpec("material", "VU", "uint8", "with coherence: basis, the texel's basis material: its cluster among "
                  "its tile's texels (0 the darkest; labels are per tile, so one label in two tiles need not be one "
                  "material); 255 where the texel had no training samples", required=False),
        ArraySpec("mip/*", "VUC", "float32", "MIP level l >= 1 of each parameter, mip/<l>/<parameter>, "
                  "(V >> l) x (U >> l) (a Mip node; attrs mip: levels, method, shapes)", required=False),
    ),
)

TextureSet = ArtifactKind(
    "TextureSet",
    1,
    "Quantized textures plus the scale/bias that decode them. Attributes: quantizer, model, model_config, "
    "bytes_per_texel, added_rms (sr^-1), added_rms_own (sr^-1, with samples), files (written beside the arrays).",
    (
        ArraySpec("textures/*", "VUK", "uint8|uint16|float16|float32", "encoded texture"),
        ArraySpec("scale/*", "K", "float64", "decode: value = texel * scale + bias"),
        ArraySpec("bias/*", "K", "float64", "decode offset"),
        ArraySpec("error", "VU", "float32", "RMS error quantizing added per texel over a uniform direction set, sr^-1"),
        ArraySpec("error_own", "VU", "float32", "RMS error quantizing added per texel over the texel's own valid "
                  "sampled directions, sr^-1 (when the Quantize node was given its samples)", required=False),
    ),
)

Images = ArtifactKind(
    "Images",
    1,
    "Rendered frames (linear float) plus EXR and PNG files beside the arrays. Attributes: renderer, timings.",
    (ArraySpec("image", "HWC", "float32", "linear RGB radiance"),),
)

Exported = ArtifactKind(
    "Exported",
    1,
    "A material written in another tool's format: the files beside the arrays (attrs 'files'), the exported "
    "parameter maps, and the conversion's error per texel. Attributes: exporter, files, error_mean/p95/max.",
    (
        ArraySpec("maps/*", "VUC", "float32", "exported parameter maps (the format's own parameters)"),
        ArraySpec("error", "VU1", "float32", "relative RMS of the exported BRDF against the input's, per texel, at "
                  "directions the conversion did not fit", required=False),
    ),
)

#: Every known kind by name: the core's six, then those plugins declare (see :func:`register_kind`).
KINDS: dict[str, ArtifactKind] = {
    k.kind: k for k in (CaptureSet, RegisteredStack, SampledReflectance, ParamMaps, TextureSet, Images, Exported)
}


def register_kind(kind: ArtifactKind, plugin: str = "") -> None:
    """Record a plugin's artifact kind; the same name declared differently is an error."""
    from .errors import PluginError

    old = KINDS.get(kind.kind)
    if old is not None and old != kind:
        raise PluginError(f"artifact kind {kind.kind!r} from plugin {plugin or '?'} is already declared differently")
    KINDS[kind.kind] = kind
