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

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sbrdf_core.errors import SbrdfError
from sbrdf_core.nodes.render import Material, open_material


@dataclass
class SceneMaterial:
    """One scene material: ``maps`` is ``(V, U, K)`` float32 in ``model.parameters`` order (K packed channels)."""

    name: str
    model: Any
    maps: np.ndarray
    alpha: np.ndarray | None  # (V, U) in [0, 1]; fragments below 0.5 are killed
    filter: str
    encoded: dict | None = None  # a TextureSet's quantizer name and NumPy textures, scale, bias
    #: A shading rule of its own instead of f_r · E · cos θ (shading maps): ``radiance(uv, wi, wo, E)`` on
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
        return bool(getattr(self.model, "anisotropic", False))

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


def from_material(name: str, material: Material, filter: str) -> SceneMaterial:
    """Compute a (lazy) :class:`~sbrdf_core.nodes.render.Material` into packed in-memory maps."""
    import dask

    model = material.model
    arrays = [material.params[p.name] for p in model.parameters]
    extra = [material.alpha] if material.alpha is not None else []
    enc = material.encoded or {}
    tex_names = sorted(enc.get("textures", {}))
    levels = list(getattr(material, "levels", None) or []) if filter == "trilinear" else []
    computed_levels = dask.compute(levels)[0] if levels else []
    computed = dask.compute(*arrays, *extra, *[enc["textures"][n] for n in tex_names])
    maps = np.concatenate([np.asarray(a, np.float32).reshape(a.shape[0], a.shape[1], -1) for a in computed[:len(arrays)]], -1)
    alpha = np.asarray(computed[len(arrays)], np.float32)[..., 0] if extra else None
    encoded = None
    if enc:
        encoded = {"quantizer": enc["quantizer"], "scale": enc["scale"], "bias": enc["bias"],
                   "textures": dict(zip(tex_names, (np.asarray(t) for t in computed[len(arrays) + len(extra):])))}
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


def resolve(scene, input_material: Material | None, registry) -> dict[str, SceneMaterial]:
    """Every material the scene's objects use, loaded once."""
    used = {o.material for o in scene.objects}
    out = {}
    from sbrdf_core.nodes.render import InputArtifact

    for name in sorted(used):
        ref = scene.materials[name]
        if isinstance(input_material, InputArtifact) and ref.artifact == "input":
            raise SbrdfError(f"{scene.file}: material {name!r} is the Render node's input, a "
                             f"{input_material.artifact.kind}: give it as shading_map: input with model: and params:")
        if ref.artifact == "input":
            if input_material is None:
                raise SbrdfError(f"{scene.file}: material {name!r} is the Render node's input, but there is none")
            out[name] = from_material(name, input_material, ref.filter)
        elif ref.artifact is not None:
            out[name] = from_material(name, open_material(registry, ref.artifact), ref.filter)
        else:
            model = registry.create("brdf-model", ref.model, dict(ref.model_params))
            if ref.shading is not None:
                shading = dict(ref.shading)
                if shading["store"] == "input":
                    if not isinstance(input_material, InputArtifact):
                        raise SbrdfError(f"{scene.file}: material {name!r} takes its shading map from the Render "
                                         "node's input, which is not a ShadingMap or PowerShadingMap")
                    shading["store"] = input_material.artifact.url
                out[name] = shading_mapped(name, model, ref.params, shading)
            else:
                out[name] = uniform(name, model, ref.params, ref.filter)
    return out


def shading_mapped(name: str, model, values: dict, shading: dict) -> SceneMaterial:
    """A shading map looked up with ``model`` (global parameters ``values``) chosen at render time."""
    try:
        from sbrdf_shading.surface import ShadingSurface
    except ImportError as e:  # pragma: no cover - the plugin ships with sbrdf
        raise SbrdfError(f"material {name!r}: shading maps need the sbrdf_shading plugin ({e})") from None
    base = uniform(name, model, values, "nearest")
    base.surface = ShadingSurface.open(shading["store"], model, model.unpack(base.maps.reshape(1, -1).astype(float)),
                                       shading["variant"], shading["above_max"], shading["sigma"])
    return base
