"""The data types of the plugin contract: what the core hands a plugin and what a plugin hands back.

:mod:`sbrdf_core.contracts` (what an implementation must provide) and
:mod:`sbrdf_core.hookspecs` (how it contributes) name these types; the node
modules build and consume them.  This module is a leaf: it imports nothing
from the engine and not even NumPy at import time, so reading the contract,
listing plugins or validating a graph never loads the engine.

=====================  ===================================  ==================================
type                   made by                              read by
=====================  ===================================  ==================================
CaptureDescription     a capture source's ``describe()``    the Capture node
Registration           a registration's ``register()``      the Register node, ``resample()``
Limits                 the Fit node                         a model's ``constrain()``
Encoded                a quantizer's ``encode()``           the Quantize node
Material               the Render node, ``load_material``   renderers, exporters
InputArtifact          the Render node                      renderers of a plugin's kind
RenderResult           a renderer's ``render()``            the Render node
PluginRegistry         the registry                         nodes, hooks, plugins that create
=====================  ===================================  ==================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import numpy as np

    from .plugin import PluginSpec

__all__ = [
    "HALF_MAX", "CaptureDescription", "Encoded", "InputArtifact", "Limits", "Material", "PluginRegistry", "Registration",
    "RenderResult",
]


# ---------------------------------------------------------------------------
# The registry, as the contract sees it
# ---------------------------------------------------------------------------


class PluginRegistry(Protocol):
    """What nodes, hooks and plugins may ask of :class:`sbrdf_core.registry.Registry`.

    A capture source creates its devices, a renderer loads further materials,
    a plugin's ``sbrdf_reference_pages`` lists what is installed, all through
    these members; the registry's loading machinery stays the engine's.
    """

    #: ``{category: {name: spec}}`` of every contribution installed.
    specs: dict[str, dict[str, PluginSpec]]
    #: ``{name: NodeKind subclass}`` of every node kind installed.
    node_kinds: dict[str, type]

    def names(self, category: str) -> list[str]:
        """The names installed in ``category``, sorted."""
        ...

    def get(self, category: str, name: str) -> PluginSpec:
        """The spec of ``name`` in ``category``, its parameters read; the error lists what is installed."""
        ...

    def load(self, spec: PluginSpec) -> Any:
        """The implementation ``spec`` names, imported once and checked against its protocol."""
        ...

    def create(self, category: str, name: str, params: dict | None = None) -> Any:
        """``params`` validated against the declaration, then the implementation constructed."""
        ...


# ---------------------------------------------------------------------------
# Capture
# ---------------------------------------------------------------------------


@dataclass
class CaptureDescription:
    """Everything about a capture except its pixels.

    ``sample``, ``camera`` and ``light`` follow the capture-folder format
    (``sbrdf-capture/1`` in DESIGN.md); ``camera["model"]`` is ``"pinhole"``
    for ordinary photographs or ``"texel-aligned"`` for images that are
    already resampled onto the texel grid (simulators).
    """

    height: int
    width: int
    light_pos: np.ndarray  # (P, 3) mm
    camera_R: np.ndarray  # (P, 3, 3)
    camera_t: np.ndarray  # (P, 3) mm
    exposure_s: np.ndarray  # (P,)
    sample: dict[str, Any] = field(default_factory=dict)
    camera: dict[str, Any] = field(default_factory=dict)
    light: dict[str, Any] = field(default_factory=dict)

    @property
    def n_poses(self) -> int:
        return int(self.light_pos.shape[0])

    def attrs(self) -> dict[str, Any]:
        return {"sample": self.sample, "camera": self.camera, "light": self.light}


# ---------------------------------------------------------------------------
# Register
# ---------------------------------------------------------------------------


@dataclass
class Registration:
    """Geometry of the accepted poses, as measured by a registration plugin."""

    texels: tuple[int, int]  # (U, V)
    size_mm: tuple[float, float]
    pose_ids: np.ndarray  # (P',) accepted capture pose indices
    light_pos: np.ndarray  # (P', 3)
    camera_pos: np.ndarray  # (P', 3)
    homography: np.ndarray  # (P', 3, 3)
    rms_mm: np.ndarray  # (P',)
    rejected: list[dict] = field(default_factory=list)  # [{"pose": i, "reason": "..."}]
    extra: dict = field(default_factory=dict)  # scalars and settings: the stack's ``registration`` attribute
    #: Other per-pose measurements, ``(P', ...)`` arrays stored as ``registration/<name>``: arrays, not
    #: attribute lists, so they cost bytes, not Python objects, per pose.
    per_pose: dict[str, np.ndarray] = field(default_factory=dict)


# ---------------------------------------------------------------------------
# Fit
# ---------------------------------------------------------------------------

#: A cosine lobe cos^n α falls to half its peak at α = √(2 ln 2 / n).
HALF_MAX = 2.0 * math.log(2.0)


@dataclass(frozen=True)
class Limits:
    """Per-texel bounds for a batch of T texels (``None``: that bound is off)."""

    #: Largest f_r (sr⁻¹, any channel) the model may reach on the hemisphere up to ``max_theta``, ``(T,)``.
    peak: np.ndarray | None = None
    #: Finest angular detail (radians) the texel's samples resolve, ``(T,)``.
    resolution: np.ndarray | None = None
    #: The hemisphere the peak bound covers, radians from the normal.
    max_theta: float = math.radians(89.0)
    #: Directional albedo bound (1: reflect at most what arrives), or ``None``.
    albedo: float | None = 1.0
    #: How much a lobe's *shape* may grow from normal incidence toward grazing (Lafortune m^n), or ``None``.
    growth: float | None = None
    #: Largest f_r·cos θ_i·cos θ_o a microfacet lobe may reach, ``(T,)``: its peak with the 1/cos² growth toward
    #: grazing (the model's physics, not an artefact of the fit) divided out.
    peak_cosine: np.ndarray | None = None

    def take(self, idx) -> Limits:
        """The limits of the texels ``idx`` (an index array or a mask)."""
        import numpy as np

        pick = lambda a: None if a is None else np.asarray(a)[idx]  # noqa: E731
        return replace(self, peak=pick(self.peak), resolution=pick(self.resolution), peak_cosine=pick(self.peak_cosine))

    def max_cosine_exponent(self) -> np.ndarray | float:
        """The sharpest cosine lobe cos^n α the sampling resolves: HWHM ≥ resolution / 2, ``(T, 1)``."""
        import numpy as np

        if self.resolution is None:
            return np.inf
        r = np.maximum(np.asarray(self.resolution, np.float64), 1e-4)[:, None]
        return 4.0 * HALF_MAX / (r * r)

    def min_roughness(self) -> np.ndarray | float:
        """The smallest microfacet slope α (Beckmann/GGX/Ward) the sampling resolves, ``(T, 1)``.

        A Gaussian in tan θ_h of width α has HWHM α√ln2 in θ_h, twice that in
        the mirror angle; requiring that to be ≥ resolution / 2 gives the bound.
        """
        import numpy as np

        if self.resolution is None:
            return 0.0
        return np.asarray(self.resolution, np.float64)[:, None] / (4.0 * np.sqrt(np.log(2.0)))


# ---------------------------------------------------------------------------
# Quantize
# ---------------------------------------------------------------------------


@dataclass
class Encoded:
    """A quantizer's ``encode`` result: ``(V, U, K)`` textures and the ``(K,)`` scale and bias that decode
    them, each a dict keyed by texture name (arrays may be lazy)."""

    textures: dict = field(default_factory=dict)
    scale: dict = field(default_factory=dict)
    bias: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------
# Render
# ---------------------------------------------------------------------------


@dataclass
class Material:
    """A BRDF model plus its (lazy) per-texel parameter maps."""

    model: Any
    params: dict[str, Any]  # name -> (V, U, C) dask array
    texels: tuple[int, int]  # (U, V)
    size_mm: tuple[float, float]
    source: str = ""
    alpha: Any = None  # (V, U, 1) transparency in [0, 1] (alpha-kill below 0.5), or None when opaque
    #: For TextureSets: the quantizer's name and its stored ``textures``, ``scale``, ``bias`` (lazy).
    encoded: dict | None = None
    #: MIP levels 1 … L (a Mip node's ``mip/<l>/<parameter>``): ``[{name: (V >> l, U >> l, C)}]``, lazy.
    levels: list = field(default_factory=list)
    #: The SampledReflectance artifact the material was fitted to, where the node was given it (an Export node's
    #: ``samples`` input: an exporter may fit its format's model to the samples instead of converting), else None.
    samples: Any = None


@dataclass
class InputArtifact:
    """A Render input of a kind a plugin renders (a shading map): renderers look its adapter up by its kind."""

    artifact: Any

    @property
    def source(self) -> str:
        return self.artifact.url


@dataclass
class RenderResult:
    """A renderer's image and how to display it."""

    image: Any  # (H, W, 3) linear RGB, lazy or NumPy
    exposure: float | None = None  # display exposure for the PNG; None = automatic
    attrs: dict = field(default_factory=dict)
    gamma: str = "srgb"  # display transfer of the PNG: "srgb" or "2.2"
