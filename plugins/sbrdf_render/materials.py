"""A scene's materials, resolved to a model and in-memory parameter maps.

Both renderers look parameters up the same way, so the CPU reference and the
GPU agree texel for texel: texel ``(i, j)`` has its centre at
``((i + ½)/U, (j + ½)/V)``, row 0 at v = 0, and textures repeat.  ``nearest``
takes the texel containing the point; ``bilinear`` blends the four nearest
centres (what ``GL_LINEAR`` with ``GL_REPEAT`` does).  ``trilinear`` (a
material with MIP levels, from a Mip node) blends the bilinear lookups of
levels ⌊λ⌋ and ⌊λ⌋ + 1 by the fraction of λ = log₂ ρ, ρ the pixel's texel
footprint (:func:`lod`), λ clamped to [0, L]: ``GL_LINEAR_MIPMAP_LINEAR``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sbrdf_core.contracts import optional
from sbrdf_core.errors import SbrdfError
from sbrdf_core.nodes.render import open_material
from sbrdf_core.types import Material

logger = logging.getLogger(__name__)


@dataclass
class SceneMaterial:
    """One scene material: ``maps`` is ``(V, U, K)`` float32 in ``model.parameters`` order (K packed channels)."""

    name: str
    model: Any
    maps: np.ndarray
    alpha: np.ndarray | None  # (V, U) in [0, 1]; fragments below 0.5 are killed
    filter: str
    encoded: dict | None = None  # a TextureSet's quantizer name and NumPy textures, scale, bias
    #: A shading rule of its own instead of f_r · E · cos θ (shading maps, through their kind's adapter):
    #: ``radiance(uv, wi, wo, E)`` on
    #: the CPU; ``glsl()``, ``glsl_radiance(wi, wo, E)``, ``gl_textures(ctx)``, ``gl_uniforms()`` on the GPU.
    surface: Any = None
    #: MIP levels 1 … L, packed like ``maps``: ``[(V >> l, U >> l, K)]`` float32 (empty: no levels).
    levels: list = field(default_factory=list)

    @property
    def trilinear(self) -> bool:
        """Lookups blend MIP levels: ``filter: trilinear`` on a material that has levels."""
        return self.filter == "trilinear" and bool(self.levels)

    @property
    def anisotropic(self) -> bool:
        return bool(optional(self.model, "anisotropic", "brdf-model"))

    def lookup(self, uv: np.ndarray, lod: np.ndarray | None = None) -> np.ndarray:
        """Packed parameters ``(R, K)`` (float64) at texture coordinates ``uv (R, 2)``.

        ``lod``: each lookup's level of detail λ (:func:`lod`), used by trilinear lookups (level 0 without it).
        """
        if self.trilinear and lod is not None:
            return sample_trilinear([self.maps] + list(self.levels), uv, lod)
        return sample(self.maps, uv, "nearest" if self.filter == "nearest" else "bilinear")

    def alive(self, uv: np.ndarray) -> np.ndarray:
        if self.alpha is None:
            return np.ones(len(uv), bool)
        return sample(self.alpha[..., None], uv, self.filter)[:, 0] >= 0.5


def sample(maps: np.ndarray, uv: np.ndarray, filter: str) -> np.ndarray:
    """Texture lookup with repeat wrapping; ``maps (V, U, K)``, ``uv (R, 2)`` -> ``(R, K)``."""
    V, U = maps.shape[:2]
    if filter == "nearest":
        i = np.floor(uv[:, 0] * U).astype(np.int64) % U
        j = np.floor(uv[:, 1] * V).astype(np.int64) % V
        return maps[j, i].astype(np.float64)
    x, y = uv[:, 0] * U - 0.5, uv[:, 1] * V - 0.5
    i0, j0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - i0)[:, None], (y - j0)[:, None]
    i1, j1 = (i0 + 1) % U, (j0 + 1) % V
    i0, j0 = i0 % U, j0 % V
    m = maps.astype(np.float64, copy=False)
    return ((1 - fy) * ((1 - fx) * m[j0, i0] + fx * m[j0, i1]) + fy * ((1 - fx) * m[j1, i0] + fx * m[j1, i1]))


def sample_trilinear(levels: list, uv: np.ndarray, lod: np.ndarray) -> np.ndarray:
    """``GL_LINEAR_MIPMAP_LINEAR``: bilinear in levels ⌊λ⌋ and ⌊λ⌋ + 1, blended by λ's fraction (λ in [0, L])."""
    L = len(levels) - 1
    lam = np.clip(np.nan_to_num(np.asarray(lod, np.float64), nan=0.0, posinf=L, neginf=0.0), 0.0, L)
    lo = np.minimum(np.floor(lam).astype(np.int64), L)
    frac = (lam - lo)[:, None]
    out = np.zeros((len(uv), levels[0].shape[-1]))
    for l in np.unique(lo):
        sel = np.nonzero(lo == l)[0]
        a = sample(levels[l], uv[sel], "bilinear")
        if l < L:
            f = frac[sel]
            a = (1 - f) * a + f * sample(levels[l + 1], uv[sel], "bilinear")
        out[sel] = a
    return out


def lod(uv: np.ndarray, valid: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """λ = log₂ ρ per pixel of an ``(H, W, 2)`` uv image (the OpenGL level of detail, no anisotropy).

    ρ = max(|∂(u U, v V)/∂x|, |∂(u U, v V)/∂y|) in texels per pixel, with derivatives taken as GPUs take
    them: differences within each 2×2 pixel quad (pixels 2k and 2k + 1 of a row or column share
    theirs).  Where the quad partner is not ``valid`` (another object, a miss) the neighbour on the other
    side is used, and λ = 0 where neither is.  ``size`` is level 0's ``(U, V)``.
    """
    H, W = valid.shape
    t = uv * np.asarray(size, np.float64)

    def deriv(axis):
        n = t.shape[axis]
        idx = np.arange(n)
        partner = idx ^ 1  # the quad partner: 2k <-> 2k + 1
        other = np.where(idx % 2 == 0, idx - 1, idx + 1)  # the neighbour on the other side
        d = np.zeros_like(t)
        ok = np.zeros(valid.shape, bool)
        for nb in (partner, other):
            inside = (nb >= 0) & (nb < n)
            nbc = np.clip(nb, 0, n - 1)
            tn, vn = np.take(t, nbc, axis=axis), np.take(valid, nbc, axis=axis)
            sign = np.where(nb > idx, 1.0, -1.0)
            shape = [1, 1]
            shape[axis] = n
            use = valid & vn & inside.reshape(shape) & ~ok
            diff = (tn - t) * sign.reshape(shape + [1])
            d[use] = diff[use]
            ok |= use
        return d, ok

    dx, okx = deriv(1)
    dy, oky = deriv(0)
    rho = np.maximum(np.linalg.norm(dx, axis=-1), np.linalg.norm(dy, axis=-1))
    with np.errstate(divide="ignore"):
        lam = np.log2(rho)
    return np.where((okx | oky) & (rho > 0), lam, 0.0)


def pack_levels(model, levels: list) -> list:
    """Computed MIP levels (``[{name: (V_l, U_l, C)}]``) packed in ``model.parameters`` order, float32."""
    return [np.concatenate([np.asarray(lv[p.name], np.float32).reshape(np.shape(lv[p.name])[0],
                                                                       np.shape(lv[p.name])[1], -1)
                            for p in model.parameters], -1) for lv in levels]


def lazy_arrays(name: str, material: Material, filter: str) -> dict:
    """What :func:`from_material` needs computed, by key (``<name>/params/<p>``, ``<name>/alpha``, …), lazy."""
    model = material.model
    out = {f"{name}/params/{p.name}": material.params[p.name] for p in model.parameters}
    if material.alpha is not None:
        out[f"{name}/alpha"] = material.alpha
    textures = (material.encoded or {}).get("textures", {})
    for n in sorted(textures):
        out[f"{name}/textures/{n}"] = textures[n]
    levels = list(getattr(material, "levels", None) or []) if filter == "trilinear" else []
    for l, lv in enumerate(levels, 1):
        out.update({f"{name}/mip/{l}/{k}": a for k, a in lv.items()})
    return out


def from_material(name: str, material: Material, filter: str, computed: dict | None = None) -> SceneMaterial:
    """A (lazy) :class:`~sbrdf_core.types.Material` as packed in-memory maps.

    ``computed``: :func:`lazy_arrays` computed (the renderer's ``prepare``, run by the runner); without it
    they are computed here (direct use outside a graph).
    """
    if computed is None:
        import dask

        computed = dask.compute(lazy_arrays(name, material, filter))[0]
    model = material.model
    arrays = [computed[f"{name}/params/{p.name}"] for p in model.parameters]
    enc = material.encoded or {}
    tex_names = sorted(enc.get("textures", {}))
    levels = list(getattr(material, "levels", None) or []) if filter == "trilinear" else []
    computed_levels = [{k: computed[f"{name}/mip/{l}/{k}"] for k in lv} for l, lv in enumerate(levels, 1)]
    maps = np.concatenate([np.asarray(a, np.float32).reshape(a.shape[0], a.shape[1], -1) for a in arrays], -1)
    alpha = np.asarray(computed[f"{name}/alpha"], np.float32)[..., 0] if material.alpha is not None else None
    encoded = None
    if enc:
        encoded = {"quantizer": enc["quantizer"], "scale": enc["scale"], "bias": enc["bias"],
                   "textures": {n: np.asarray(computed[f"{name}/textures/{n}"]) for n in tex_names}}
    return SceneMaterial(name, model, maps, alpha, filter, encoded, levels=pack_levels(model, computed_levels))


def uniform(name: str, model, values: dict, filter: str = "nearest") -> SceneMaterial:
    """A 1×1 material from a model and parameter values (scalars or per-channel lists); missing ones default."""
    unknown = set(values) - {p.name for p in model.parameters}
    if unknown:
        raise SbrdfError(f"material {name!r}: unknown parameter(s) {sorted(unknown)} for model {model.name!r}; "
                         f"accepted: {[p.name for p in model.parameters]}")
    packed = []
    for p in model.parameters:
        v = np.asarray(values.get(p.name, p.default), dtype=np.float64).reshape(-1)
        if v.size not in (1, p.channels):
            raise SbrdfError(f"material {name!r}: parameter {p.name!r} needs 1 or {p.channels} values, got {v.size}")
        v = np.broadcast_to(v, (p.channels,))
        lo, hi = p.bounds
        if not np.all(np.isfinite(v)) or np.any(v < lo) or np.any(v > hi):
            raise SbrdfError(f"material {name!r}: parameter {p.name!r} = {v.tolist()} is outside its bounds [{lo}, {hi}]")
        packed.append(v)
    return SceneMaterial(name, model, np.concatenate(packed).astype(np.float32)[None, None], None, filter)


def inputs(scene, input_material, registry) -> dict[str, Material]:
    """The scene's materials that come from stores (the Render node's input, ``artifact:`` paths), lazy, by name."""
    out = {}
    for name in sorted({o.material for o in scene.objects}):
        ref = scene.materials[name]
        if ref.artifact == "input" and isinstance(input_material, Material):
            out[name] = input_material
        elif ref.artifact not in (None, "input"):
            out[name] = open_material(registry, ref.artifact)
    return out


def prepare(scene, input_material, registry) -> dict:
    """Every array the scene's store-backed materials need, lazy (a renderer's ``prepare``)."""
    out = {}
    for name, m in inputs(scene, input_material, registry).items():
        out.update(lazy_arrays(name, m, scene.materials[name].filter))
    return out


def resolve(scene, input_material: Material | None, registry, prepared: dict | None = None) -> dict[str, SceneMaterial]:
    """Every material the scene's objects use, loaded once; ``prepared``: :func:`prepare` computed."""
    used = {o.material for o in scene.objects}
    out = {}
    from sbrdf_core.types import InputArtifact

    stored = None
    for name in sorted(used):
        ref = scene.materials[name]
        if isinstance(input_material, InputArtifact) and ref.artifact == "input":
            raise SbrdfError(f"{scene.file}: material {name!r} is the Render node's input, a "
                             f"{input_material.artifact.kind}: give it as {_store_keys(registry)}: input with model: "
                             "and params:")
        if ref.artifact == "input" and input_material is None:
            raise SbrdfError(f"{scene.file}: material {name!r} is the Render node's input, but there is none")
        if ref.artifact is not None:
            if stored is None:
                stored = inputs(scene, input_material, registry)
            out[name] = from_material(name, stored[name], ref.filter, prepared)
        else:
            model = registry.create("brdf-model", ref.model, dict(ref.model_params))
            if ref.surface is not None:
                out[name] = surface_mapped(scene, name, model, ref, input_material)
            else:
                out[name] = uniform(name, model, ref.params, ref.filter)
    return out


def _store_keys(registry) -> str:
    """The material keys that take a renderable store (``shading_map``), as a scene would write them."""
    from sbrdf_lib.scene import plugin_keys

    keys = [p.name for p in plugin_keys(registry).material_params if (p.extra or {}).get("store")]
    return " or ".join(keys) or "a store key"


def surface_mapped(scene, name: str, model, ref, input_material) -> SceneMaterial:
    """A material of a renderable artifact kind (a shading map), looked up with ``model`` chosen at render time.

    The store's kind names its adapter (``ArtifactKind.material``, from the plugin that declares the kind):
    ``adapter(artifact, model, params, **options) -> surface``.
    """
    from sbrdf_core.artifacts import KINDS
    from sbrdf_core.registry import import_path
    from sbrdf_core.store import open_artifact
    from sbrdf_core.types import InputArtifact

    surface = ref.surface
    if surface["store"] == "input":
        if not isinstance(input_material, InputArtifact):
            kinds = " or ".join(k.kind for k in KINDS.values() if k.material)
            raise SbrdfError(f"{scene.file}: material {name!r} takes its {surface['key']} from the Render "
                             f"node's input, which is not a {kinds}")
        art = input_material.artifact
    else:
        art = open_artifact(surface["store"], tuple(k.kind for k in KINDS.values() if k.material))
    kind = KINDS.get(art.kind)
    if kind is None or not kind.material:
        raise SbrdfError(f"material {name!r}: {art.url} is a {art.kind}, which no installed plugin renders")
    base = uniform(name, model, ref.params, "nearest")
    adapter = import_path(kind.material)
    base.surface = adapter(art, model, model.unpack(base.maps.reshape(1, -1).astype(float)), **surface["options"])
    return base
