"""What a contribution must provide: one :class:`typing.Protocol` per category.

The hooks in :mod:`sbrdf_core.hookspecs` say *how* a plugin contributes (a
list of :class:`~sbrdf_core.plugin.PluginSpec`); this module says *what* the
implementation a spec names must be.  Each protocol lists the required
members; the optional ones, with what the framework does when a plugin leaves
them out, are declared in :data:`OPTIONAL` beside it, and the core reaches
them only through :func:`optional` so that every optional capability is
written down here and nowhere else.

:meth:`sbrdf_core.registry.Registry.load` checks an implementation against its
protocol the first time it is imported, naming the missing members;
:mod:`sbrdf_core.testing` holds the behavioural suites a plugin author runs in
their own tests; the plugin guide's table is generated from this module
(:func:`contract_table`).
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

if TYPE_CHECKING:  # the contract never imports the engine or numpy at runtime
    import numpy as np

    from .brdf import ModelParameter
    from .types import CaptureDescription, Encoded, InputArtifact, Limits, Material, RenderResult
    from .types import Registration as RegistrationResult


# ---------------------------------------------------------------------------
# Capture and devices
# ---------------------------------------------------------------------------


@runtime_checkable
class CaptureSource(Protocol):
    """The ``plugin:`` of a ``Capture`` node: where the photographs come from."""

    def describe(self) -> CaptureDescription:
        """Pose count, image size, per-pose light and camera metadata; no pixels."""

    def read_pose(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """``(image (H, W, 3) float32 linear relative radiance, valid (H, W) bool)`` of one pose."""


@runtime_checkable
class MotorController(Protocol):
    """A device with axes (pan-tilt unit, indexer) that a capture source drives.

    Devices are created by capture sources through
    ``registry.create("device", name, params)``, never by graphs.
    """

    def move_to(self, **targets: float) -> dict[str, float]:
        """Move the named axes; return the positions reached (verified)."""

    def position(self) -> dict[str, float]:
        """Where every axis is now."""

    def stop(self) -> None:
        """Halt every axis (safe to call at any time, also after a failure)."""

    def close(self) -> None:
        """Release the link."""


@runtime_checkable
class Camera(Protocol):
    """A device that photographs the sample for a capture source."""

    def photograph(self, light_pos_mm: np.ndarray, R: np.ndarray, t: np.ndarray, exposure_s: float,
                   **kw: Any) -> np.ndarray:
        """One raw exposure of the sample lit from ``light_pos_mm`` seen from camera pose ``(R, t)``."""


# ---------------------------------------------------------------------------
# Register
# ---------------------------------------------------------------------------


@runtime_checkable
class Registration(Protocol):
    """The ``plugin:`` of a ``Register`` node: photographs onto the texel grid."""

    def register(self, capture: Any, **kw: Any) -> RegistrationResult:
        """Texel grid and per-pose geometry of the opened ``CaptureSet`` (``prepared=`` if it declares ``prepare``)."""

    def resample(self, image: np.ndarray, valid: np.ndarray, pose: int, registration: Any) -> tuple[np.ndarray, np.ndarray]:
        """One accepted pose resampled onto the ``(V, U)`` texel grid; pure NumPy, runs inside dask tasks."""


# ---------------------------------------------------------------------------
# Fit
# ---------------------------------------------------------------------------


@runtime_checkable
class BRDFModel(Protocol):
    """A BRDF model: what fitters fit, quantizers store and renderers shade.

    Implementations subclass :class:`sbrdf_core.brdf.BRDFModel`, which
    supplies everything here except ``name``, ``parameters``, ``eval`` and
    ``glsl``; the base class's defaults are the documented fallbacks.
    """

    name: ClassVar[str]
    parameters: tuple[ModelParameter, ...]

    def eval(self, params: Mapping[str, np.ndarray], wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """f_r (sr^-1) for per-texel ``params`` and directions ``(T, S, 3)`` in the surface frame -> ``(T, S, 3)``."""

    def jacobian(self, params: Mapping[str, np.ndarray], wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """d f_r / d parameters, ``(T, S, 3, P)`` in :meth:`pack` order (the base class differentiates numerically)."""

    def glsl(self) -> str:
        """GLSL of ``vec3 brdf_<name>(vec3 wi, vec3 wo, ...)`` computing the same f_r per pixel."""

    def glsl_call(self, wi: str, wo: str, args: Mapping[str, str]) -> str:
        """The GLSL expression calling it."""

    def fit_form(self) -> BRDFModel:
        """The change of variables fitters work in (log exponents, a fixed gauge)."""

    def initial_guess(self, f_r: np.ndarray, valid: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> dict[str, np.ndarray]:
        """A deterministic, data-driven start for every texel."""

    def constrain(self, params: Mapping[str, np.ndarray], limits: Limits) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Project parameters into the physical bounds; also return which texels it changed."""

    def defaults(self, T: int) -> dict[str, np.ndarray]:
        """Parameter maps for ``T`` texels nobody fitted."""

    def pack(self, params: Mapping[str, np.ndarray]) -> np.ndarray:
        """Per-texel parameter vectors ``(T, P)``."""

    def unpack(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """The inverse of :meth:`pack`."""

    @property
    def size(self) -> int:
        """Length of the packed per-texel vector (the base class: the sum of the parameters' channels)."""


@runtime_checkable
class Fitter(Protocol):
    """The ``plugin:`` of a ``Fit`` node: per-texel parameters from sampled reflectance."""

    #: Registry name and configuration of the BRDF model it fits; the Fit node creates the model.
    model_name: str
    model_config: dict

    def fit(self, model: BRDFModel, f_r: np.ndarray, valid: np.ndarray, wi: np.ndarray, wo: np.ndarray, *,
            limits: Limits | None = None, rms: bool = True, usable: bool = False,
            initial: Mapping[str, np.ndarray] | None = None) -> Any:
        """A ``FitResult`` for T texels with S samples each.

        ``f_r (T, S, 3)`` sr^-1, ``valid (T, S)`` (held-out samples already
        removed), directions ``(T, S, 3)`` in the sample frame.  ``limits``
        (:class:`~sbrdf_core.constraints.Limits`) are the texels' physical
        bounds: fit inside them where the fitter can (the node projects
        whatever comes back onto them anyway).  ``rms`` False (the Fit node's:
        it scores the fit itself): ``FitResult.rms`` may be ``None``.
        ``usable`` True (the Fit node's): the samples are
        :func:`~sbrdf_core.nodes.fit.usable`'s already (float64, finite, 0
        where not ``valid``), so a fitter that tests them may skip that.
        ``initial`` (model-form parameters, ``(T, C)`` each): a solution to
        refine rather than the fitter's own starts; the Fit node passes a
        neighbour's solution this way when it fits the texel better
        (``coherence``).  A fitter that cannot start from a given point ignores
        it.  Every fitter accepts all four keywords, using what applies to it.
        Vectorised over texels; runs inside dask tasks, one tile at a time.
        """


@runtime_checkable
class Parameterization(Protocol):
    """A change of variables of a BRDF into two 2D factor domains (separable BRDFs)."""

    wrap: Any  #: per factor, per texture axis: whether the axis is periodic

    def coords(self, wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Texture coordinates ``(..., 2)`` in [0, 1]^2 of both factors."""

    def directions(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The inverse, broadcasting ``x`` against ``y``."""

    def glsl(self) -> str:
        """``void sep_coords(vec3 wi, vec3 wo, out vec2 x, out vec2 y)``."""


# ---------------------------------------------------------------------------
# Quantize and render
# ---------------------------------------------------------------------------


@runtime_checkable
class Quantizer(Protocol):
    """The ``plugin:`` of a ``Quantize`` node: a texture layout."""

    def encode(self, params: Mapping[str, Any], model: BRDFModel, **kw: Any) -> Encoded:
        """Lazy textures ``(V, U, K)`` plus per-channel ``scale`` and ``bias``."""

    def decode(self, textures: Mapping[str, Any], scale: Mapping[str, Any], bias: Mapping[str, Any],
               model: BRDFModel) -> dict[str, Any]:
        """Parameter maps back, elementwise (NumPy or dask); independent of the plugin's parameters."""


@runtime_checkable
class Renderer(Protocol):
    """The ``plugin:`` of a ``Render`` node."""

    def render(self, material: Material | InputArtifact, prepared: Mapping[str, Any] | None = None) -> RenderResult:
        """An image (lazy or NumPy) of the material.

        ``material`` is a :class:`~sbrdf_core.types.Material` for a ParamMaps or
        TextureSet input, and an :class:`~sbrdf_core.types.InputArtifact` for a
        kind a plugin declares renderable (a shading map).  ``prepared`` is what
        the renderer's ``prepare`` returned, computed; it is passed only to a
        renderer that declares ``prepare``.
        """


@runtime_checkable
class SceneEffect(Protocol):
    """Radiance the ``cpu`` and ``gl`` renderers add to L (environment light, mirrors).

    A renderer constructs and runs only the effects a scene wants, so a scene
    pays for nothing it does not use.
    """

    @staticmethod
    def wanted(scene: Any) -> bool:
        """Whether the scene calls for the effect."""

    @staticmethod
    def options(scene: Any) -> dict:
        """The effect's parameter values from the scene file (validated against its declaration)."""

    def prepare(self, scene: Any, materials: Mapping[str, Any], gl_context: Any = None) -> None:
        """Load data and precompute; ``gl_context`` is given by the ``gl`` renderer."""

    def cpu_radiance(self, material: Any, hits: Any, view_dirs: np.ndarray, pixels: Any) -> np.ndarray:
        """Radiance ``(R, 3)`` at ray hits of one material seen along ``view_dirs``."""

    def glsl(self, material: Any, exprs: Mapping[str, str]) -> tuple[str, str]:
        """``(declarations, statements)`` added to the fragment shader after the lights."""


@runtime_checkable
class Exporter(Protocol):
    """The ``plugin:`` of an ``Export`` node: a material in another tool's format."""

    def convert(self, material: Material) -> dict[str, Any]:
        """Lazy ``(V, U, C)`` maps of the format's parameters, optionally ``error`` ``(V, U, 1)`` (relative, per texel)."""

    def write(self, directory: str, maps: Mapping[str, np.ndarray], material: Material) -> dict:
        """Write the files beside the stored maps; return attributes, at least ``{"files": [...]}``."""


@runtime_checkable
class Command(Protocol):
    """A ``sbrdf <name>`` subcommand (the viewer's ``sbrdf view``)."""

    @staticmethod
    def add_arguments(parser: Any) -> None:
        """Declare the subcommand's arguments on its ``argparse`` parser."""

    def run(self, args: Any) -> int:
        """Run with the parsed arguments; the exit status."""


# ---------------------------------------------------------------------------
# Optional members: declared once, with the framework's fallback
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class OptionalMember:
    """An optional member of a protocol: what it is for and what happens without it."""

    doc: str
    default: Any = None


_COMMON = {
    "bind": OptionalMember("`bind(registry)`: called after construction with the run's registry, for implementations "
                     "that look up other plugins (a model, a device, a quantizer) by name instead of importing them.",
                     None),
    "check_params": OptionalMember("`check_params(values[, registry]) -> [(key, message)]` (static): problems a graph has "
                             "that the declared parameters cannot express, reported by `sbrdf validate` with file:line.",
                             None),
}

#: Per category: optional member name -> :class:`OptionalMember`.
OPTIONAL: dict[str, dict[str, OptionalMember]] = {
    "capture": {
        **_COMMON,
        "sequential": OptionalMember("`sequential` (class attribute): poses must be taken one at a time, in order, in this "
                               "process (hardware).", False),
        "fingerprint": OptionalMember("`fingerprint() -> str`: changes when the source's data changes, so cached results "
                                "are redone.", None),
        "read_report": OptionalMember("`read_report() -> (line, attrs) or None`: what reading the poses in this process "
                                      "found (poses with pixels made invalid, the worst one), asked once every pose "
                                      "is written: the Capture node logs the line as one warning and stores `attrs` "
                                      "on the CaptureSet, so a source warns once per node, not once per pose.", None),
        "calibrate": OptionalMember("`calibrate(*, dark_offset, dark_rate, flat)`: correct every exposure with the "
                                    "Capture node's `dark` (DarkFrame) and `flat` (FlatField) inputs, `(H, W, 3)` "
                                    "arrays in linear signal units, before the bracket is merged; called before "
                                    "`describe`. Without it the node refuses those inputs.", None),
    },
    "device": {**_COMMON},
    "registration": {
        **_COMMON,
        "prepare": OptionalMember("`prepare(capture) -> {name: dask collection}`: data `register` needs computed (markers "
                            "found in the photographs); the runner computes it on the run's scheduler with progress "
                            "and passes `prepared=` to `register`.", None),
    },
    "brdf-model": {
        "anisotropic": OptionalMember("`anisotropic`: the model needs a tangent frame.", True),
        "two_sided": OptionalMember("`two_sided`: the model also shades the back face (transmission).", False),
        "albedo_bound": OptionalMember("`albedo_bound(params)`: a cheap upper bound of directional albedo, so only "
                                 "texels it does not clear are integrated.", None),
        "gl_textures": OptionalMember("`gl_textures() -> {uniform: array}`: textures the model's GLSL samples (a "
                                      "tabulated model's table), uploaded by the gl renderer.", None),
        "suggested_starts": OptionalMember("`suggested_starts`: how many starts a multi-start fit should use.", 2),
        "reads_peak_cosine": OptionalMember("`reads_peak_cosine`: `constrain` reads `Limits.peak_cosine` (a "
                                            "microfacet lobe's peak bound on f_r cos θ_i cos θ_o, "
                                            "`constraints.widen_to_peak`); False: the Fit node does not compute "
                                            "that support.", True),
        "fit_kernel": OptionalMember("`fit_kernel(x, cfg, wi, wo, f, J)` (a module-level function, on the fit form): "
                                     "f_r (nc,) and ∂f_r/∂x (nc, K) at one direction pair, in plain Python on "
                                     "scalars and `math`; the fitting engine (`sbrdf_core.engine`) compiles it into "
                                     "its Levenberg–Marquardt loop, and `sbrdf_core.engine_glsl` translates it into "
                                     "the GLSL `brdf_fit_gradient` the GPU fitter `lm-gl` runs (so it must keep to "
                                     "the Python subset listed there). Without it: the NumPy path (`eval`, "
                                     "`jacobian`), far slower, and `lm-gl` refuses the model, naming it.", None),
        "kernel_config": OptionalMember("`kernel_config() -> (n,) float64`: the options `fit_kernel` reads (flags, "
                                        "choices as numbers).", None),
        "nested": OptionalMember("`nested() -> (smaller model, embed) or None` (on the fit form): a model this one "
                                 "contains (Lafortune with a lobe fewer) and `embed(x_small) -> x`, its packed "
                                 "fit-form rows as this form's; `lm` fits the smaller model first and keeps, per "
                                 "texel, the lower cost, so more freedom never fits the training data worse.", None),
        "fit_trapped": OptionalMember("`fit_trapped(x) -> (T,) bool` (on the fit form): packed fit-form rows where LM is "
                                      "known to stall (a lobe with no magnitude gets no gradient in its shape); `lm` "
                                      "and `lm-gl` fit them again (from the form's variable-projection fit where it "
                                      "has one, else from the best multi-start candidates) and keep the lower cost "
                                      "(`sbrdf_lib.lm.rescue`).", None),
        "fit_outlier_ratio": OptionalMember("`fit_outlier_ratio` (on the fit form): a texel whose cost per valid sample "
                                            "is over this multiple of its tile's median is fitted again as a "
                                            "`fit_trapped` one (LM stalls without a dead lobe to show for it: two "
                                            "lobes on one feature); None: never.", None),
        "max_step": OptionalMember("`max_step` (on the fit form): `(K,)` the longest change of each packed "
                                   "parameter in one LM step (inf: no limit); `lm` and `lm-gl` shorten a longer "
                                   "step along its direction (`sbrdf_lib.lm.limit_step`), so a Gauss–Newton step "
                                   "far past where the model is near linear does not cost a run of rejected "
                                   "trials.", None),
        "project_kernel": OptionalMember("`project_kernel(x, cfg, lim, lo, hi)` (a module-level function, on the fit "
                                         "form): `constrain` on one packed row `x` in place, inside the box `lo`, `hi`, "
                                         "with `lim` the texel's row of `project_limits(limits, T) -> (T, m)`; the "
                                         "fitting engine compiles it into its loop. Without it (and without "
                                         "`widens_to_peak`): `constrain` after the loop and a NumPy refinement of "
                                         "what it moved.", None),
        "glsl_fit_constrain": OptionalMember("`glsl_fit_constrain() -> str`: GLSL (4.3) defining `void brdf_fit_constrain("
                                             "inout float x[K], float peak, float resolution, float peak_cosine, float "
                                             "growth, float max_theta)`, the fit form's `constrain` onto the texel's "
                                             "limits (a negative value: that bound is off; `sbrdf_core.constraints_glsl`),"
                                             " so `lm-gl` projects every trial point in its shader; without it `lm-gl` "
                                             "refits texels that leave their limits stepwise, projecting each trial "
                                             "point on the CPU.", None),
    },
    "fitter": {**_COMMON},
    "parameterization": {},
    "exporter": {**_COMMON},
    "command": {"bind": _COMMON["bind"]},
    "quantizer": {
        **_COMMON,
        "prepare": OptionalMember("`prepare(params, model) -> {name: dask collection}`: global statistics (a palette's "
                            "clustering) the runner computes before `encode(..., prepared=)`.", None),
        "write_files": OptionalMember("`write_files(art, textures, scale, bias, model) -> attrs`: files beside the arrays "
                                "(EXR, JSON, PNG), written once every chunk is.", None),
        "bytes_per_texel": OptionalMember("`bytes_per_texel(textures) -> float`: when the stored arrays are not what a "
                                    "renderer would hold (palette indices plus a shared palette).", None),
    },
    "renderer": {
        **_COMMON,
        "prepare": OptionalMember("`prepare(material) -> {name: dask collection}`: the parameter maps and levels the "
                            "renderer needs in memory, computed by the runner before `render(..., prepared=)`.", None),
    },
    "scene-effect": {
        "check": OptionalMember("`check(scene) -> [str]`: cheap checks of what `prepare` will need, run at validation.", None),
        "gl_prepare": OptionalMember("`gl_prepare(drawer)`: GPU set-up with the gl renderer's scene.", None),
        "gl_uniforms": OptionalMember("`gl_uniforms(program, first_unit) -> units used`.", None),
        "gl_use": OptionalMember("`gl_use(first_unit) -> units used`: bind its textures before a draw.", None),
        "gl_frame": OptionalMember("`gl_frame(drawer)`: before each frame (extra passes, per-frame uniforms).", None),
        "release": OptionalMember("`release()`: free GPU resources.", None),
    },
}

#: Category -> protocol, or protocols of which one must hold (artifact kinds are data:
#: :class:`sbrdf_core.artifacts.ArtifactKind`).
PROTOCOLS: dict[str, type | tuple[type, ...]] = {
    "capture": CaptureSource,
    "device": (MotorController, Camera),  # a device is one or the other
    "registration": Registration,
    "brdf-model": BRDFModel,
    "fitter": Fitter,
    "parameterization": Parameterization,
    "quantizer": Quantizer,
    "renderer": Renderer,
    "scene-effect": SceneEffect,
    "exporter": Exporter,
    "command": Command,
}


def optional(obj: Any, name: str, category: str | None = None) -> Any:
    """``obj.name`` if the implementation has it, else the declared default.

    The one place the core asks whether a plugin has a capability; a name not
    declared in :data:`OPTIONAL` is a programming error, so capabilities
    cannot appear without documentation.
    """
    declared = [c for c, members in OPTIONAL.items() if name in members and (category is None or c == category)]
    if not declared:
        raise KeyError(f"{name!r} is not a declared optional member{f' of {category}' if category else ''}")
    try:
        return getattr(obj, name)
    except AttributeError:
        return OPTIONAL[declared[0]][name].default


def required_members(protocol: type) -> list[str]:
    """Names a protocol requires (methods and attributes), in declaration order."""
    names = [n for n in protocol.__dict__ if not n.startswith("_")]
    names += [n for n in getattr(protocol, "__annotations__", {}) if not n.startswith("_") and n not in names]
    return names


def missing(category: str, impl: Any) -> list[str]:
    """Required members of ``category``'s protocol that ``impl`` (a class or object) lacks.

    Attributes set in ``__init__`` cannot be seen on a class; annotations
    count, so a class declaring ``model_name: str`` satisfies the protocol.
    """
    protocol = PROTOCOLS.get(category)
    if protocol is None:
        return []
    if isinstance(protocol, tuple):
        return min((_missing(p, impl) for p in protocol), key=len)
    return _missing(protocol, impl)


def _missing(protocol: type, impl: Any) -> list[str]:
    have = set(dir(impl))
    for klass in inspect.getmro(impl) if inspect.isclass(impl) else [type(impl)]:
        have |= set(getattr(klass, "__annotations__", {}))
    if inspect.isclass(impl) and "__init__" in vars(impl):  # attributes assigned in __init__: self.x = ...
        try:
            src = inspect.getsource(impl.__init__)
        except (OSError, TypeError):
            src = ""
        have |= {n for n in required_members(protocol) if f"self.{n} =" in src or f"self.{n}:" in src}
    return [n for n in required_members(protocol) if n not in have]


def contract_table() -> str:
    """The plugin guide's table: per category, required and optional members (Markdown)."""
    from .plugin import CATEGORIES

    rows = ["| category (hook) | protocol | required | optional |", "|---|---|---|---|"]
    for category, hook in CATEGORIES.items():
        protos = PROTOCOLS[category]
        protos = protos if isinstance(protos, tuple) else (protos,)
        req = " or ".join(", ".join(f"`{n}`" for n in required_members(p)) for p in protos)
        opt = ", ".join(f"`{n}`" for n in OPTIONAL.get(category, {})) or "–"
        name = " or ".join(f"`{p.__name__}`" for p in protos)
        rows.append(f"| {category} (`{hook}`) | {name} | {req} | {opt} |")
    rows.append("| artifact kind (`sbrdf_artifact_kinds`) | `sbrdf_core.artifacts.ArtifactKind` (data) | "
                "`kind`, `version`, `doc`, `arrays` | `material` |")
    return "\n".join(rows)


def optional_table() -> str:
    """Every optional member with its meaning and fallback (Markdown)."""
    rows = ["| category | member | what it is for | without it |", "|---|---|---|---|"]
    for category, members in OPTIONAL.items():
        for name, o in members.items():
            rows.append(f"| {category} | `{name}` | {o.doc} | `{o.default!r}` |")
    return "\n".join(rows)


__all__ = [
    "BRDFModel", "Camera", "CaptureSource", "Command", "Exporter", "MotorController", "Fitter", "OPTIONAL", "OptionalMember", "PROTOCOLS", "Parameterization",
    "Quantizer", "Registration", "Renderer", "SceneEffect", "contract_table", "missing", "optional",
    "optional_table", "required_members",
]


# ---------------------------------------------------------------------------
# Frame cameras: physical cameras (and their vendors' emulators)
# ---------------------------------------------------------------------------


@runtime_checkable
class FrameCamera(Protocol):
    """A physical camera that a capture source configures once, then triggers frame by frame.

    Unlike :class:`Camera` (the virtual camera, which renders the sample for a
    given light and pose) it knows nothing of the scene: the ``gonio`` source
    moves the motors, waits for them to settle, sets the exposure and grabs.
    :mod:`sbrdf_lib.camera` holds the base class the built-in drivers share
    and the errors they raise.  Invariants every implementation keeps:

    * ``grab`` returns ``(H, W, 3)`` uint8 or uint16 codes, MSB-aligned (full
      scale is the dtype's maximum whatever the bit depth); a mono code is
      repeated in the three channels;
    * automatic exposure, gain and white balance are off where the camera has
      them, so a code depends only on radiance, exposure time and gain;
    * ``info()`` says who the camera is and how it is set (vendor, model,
      serial, pixel format, bit depth, linear readout, gain, black level,
      trigger, white balance "off"): the capture records it;
    * failures raise :class:`sbrdf_lib.camera.CameraError` subclasses
      (``CameraLost``, ``FrameTimeout``, ``ExposureRefused``).
    """

    def info(self) -> dict:
        """Identity and settings of the camera, recorded in the capture's ``camera.device``."""

    def exposure_range_s(self) -> tuple[float, float]:
        """``(shortest, longest)`` exposure time the camera accepts, s (checked before anything moves)."""

    def set_exposure(self, exposure_s: float) -> float:
        """Set the exposure; return the time the camera actually uses (refused outside the range)."""

    def grab(self, *, timeout_s: float | None = None, **kw: Any) -> np.ndarray:
        """Trigger (or await a hardware trigger for) one frame; ``(H, W, 3)`` uint8/uint16 codes."""

    def close(self) -> None:
        """Stop acquisition and release the camera; idempotent."""


# A device is a motor controller, a scene-rendering camera or a frame camera.
PROTOCOLS["device"] = (MotorController, Camera, FrameCamera)
__all__ += ["FrameCamera"]
