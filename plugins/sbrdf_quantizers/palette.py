"""palette: K ≤ 256 representative BRDFs and an 8-bit index image (seed 000 §4.6, the paint round trip).

Texels are clustered in *sampled-BRDF space*: each texel's BRDF evaluated at
a fixed set of direction pairs (all pairs of a Fibonacci set, θ ≤ 85°) is one
vector, so the Euclidean distance between two texels is √S times the RMS
difference of their BRDFs in sr⁻¹, the error the Quantize node reports.
Parameter space would be wrong: lobes with (e·ρ_s, C·e^(−1/n)) are the same
BRDF at different parameters, and n = 50 vs 60 matters far less than ρ_d
0.1 vs 0.2.  k-means (k-means++ seeding, Lloyd iterations, on at most
``train`` texels, then every texel assigned) gives the clusters; each palette
entry is the cluster's *medoid*, the member texel nearest the cluster mean,
so every palette BRDF is a fitted, valid parameter set (the mean of the sampled
vectors is valid too, Eq 5.2–5.16, but would need a refit to become parameters).

Textures: ``index`` ``(V, U, 1)`` uint8, and ``palette/<parameter>``
``(1, K, C)`` float32 (a 1×K texture per parameter).  ``write_files`` writes
``index.png`` (8-bit grey) and ``palette.json`` beside the arrays.

The paint round trip: edit ``index.png`` in any paint program, then
:func:`resynthesize` compares the original and edited index images and, for
each changed texel only, replaces the SBRDF texel with the palette BRDF; every
other texel keeps its full-precision fitted parameters.
"""

from __future__ import annotations

import json

import numpy as np

from sbrdf_core.geometry import fibonacci_hemisphere
from sbrdf_core.io import read_png, write_png
from sbrdf_core.store import join
from sbrdf_core.types import Encoded

from .declarations import PALETTE


def sample_directions(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """``(1, n², 3)`` ω_i, ω_r: all pairs of ``n`` Fibonacci directions (θ ≤ 85°)."""
    d = fibonacci_hemisphere(n, max_theta_deg=85.0)
    return np.repeat(d, n, axis=0)[None], np.tile(d, (n, 1))[None]


def sampled_vectors(model, params: dict, n_dirs: int = 12, batch: int = 4096) -> np.ndarray:
    """Each texel's BRDF as a vector ``(T, n_dirs² · 3)`` in sr⁻¹; ``params`` are ``(T, C)``."""
    wi, wo = sample_directions(n_dirs)
    T = next(iter(params.values())).shape[0]
    out = np.empty((T, wi.shape[1] * 3), np.float32)
    for s in range(0, T, batch):  # bounded memory; each batch is one vectorised eval
        e = min(T, s + batch)
        sub = {k: np.asarray(v[s:e], np.float64) for k, v in params.items()}
        out[s:e] = model.eval(sub, np.broadcast_to(wi, (e - s,) + wi.shape[1:]),
                              np.broadcast_to(wo, (e - s,) + wo.shape[1:])).reshape(e - s, -1)
    return out


def _nearest(x: np.ndarray, centres: np.ndarray, batch: int = 8192) -> tuple[np.ndarray, np.ndarray]:
    """Index of and squared distance to the nearest centre per row."""
    cc = (centres.astype(np.float64) ** 2).sum(axis=1)
    idx = np.empty(len(x), np.int64)
    dist = np.empty(len(x))
    for s in range(0, len(x), batch):
        xb = x[s:s + batch].astype(np.float64)
        d = (xb ** 2).sum(axis=1)[:, None] - 2 * xb @ centres.T.astype(np.float64) + cc[None]
        idx[s:s + batch] = d.argmin(axis=1)
        dist[s:s + batch] = np.maximum(d[np.arange(len(xb)), idx[s:s + batch]], 0.0)
    return idx, dist


def kmeans(x: np.ndarray, k: int, iterations: int = 20, seed: int = 0, train: int = 20000):
    """k-means in sampled-BRDF space: ``(labels (T,), centres (k', D))``, k' ≤ k distinct clusters."""
    rng = np.random.default_rng(seed)
    T = len(x)
    sub = x[rng.choice(T, train, replace=False)] if T > train else x
    k = min(k, len(np.unique(sub, axis=0)))
    # k-means++ seeding
    seeds = [sub[rng.integers(len(sub))]]
    d2 = ((sub - seeds[0]) ** 2).sum(axis=1).astype(np.float64)
    for _ in range(1, k):
        p = d2 / d2.sum() if d2.sum() > 0 else None
        c = sub[rng.choice(len(sub), p=p)]
        seeds.append(c)
        d2 = np.minimum(d2, ((sub - c) ** 2).sum(axis=1))
    centres = np.array(seeds, np.float64)
    for _ in range(iterations):
        lab, _ = _nearest(sub, centres)
        counts = np.bincount(lab, minlength=k)
        sums = np.zeros_like(centres)
        np.add.at(sums, lab, sub)
        moved = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], centres)
        if np.allclose(moved, centres):
            break
        centres = moved
    labels, _ = _nearest(x, centres)
    return labels, centres


def build_palette(model, params: dict, k: int = 256, n_dirs: int = 12, seed: int = 0):
    """Cluster ``params`` (``(T, C)`` each) into ≤ k BRDFs.

    Returns ``(index (T,) uint8, palette {name: (k', C)}, medoid texel per entry (k',))``.
    """
    if not 1 <= k <= 256:
        raise ValueError(f"palette: k must be in [1, 256] (an 8-bit index), got {k}")
    x = sampled_vectors(model, params, n_dirs)
    labels, centres = kmeans(x, k, seed=seed)
    used = np.unique(labels)
    remap = np.full(len(centres), -1)
    remap[used] = np.arange(len(used))
    labels = remap[labels]
    # medoid: per cluster, the member nearest the cluster mean (vectorised: distance of every texel to its own mean)
    means = np.zeros((len(used), x.shape[1]))
    np.add.at(means, labels, x)
    means /= np.bincount(labels, minlength=len(used))[:, None]
    d = ((x - means[labels]) ** 2).sum(axis=1)
    order = np.lexsort((d, labels))  # by cluster, then distance
    first = order[np.searchsorted(labels[order], np.arange(len(used)))]
    palette = {n: np.asarray(v)[first].astype(np.float32) for n, v in params.items()}
    return labels.astype(np.uint8), palette, first


def resynthesize(params: dict, original_index: np.ndarray, edited_index: np.ndarray, palette: dict):
    """Apply a painted index image: texels whose index changed get that palette BRDF, the rest are untouched.

    ``params`` ``name -> (V, U, C)``; index images ``(V, U)`` (or ``(V, U, 1|3|4)``: the first channel).
    Returns ``(new params, changed mask (V, U))``.
    """
    a, b = (np.asarray(i)[..., 0] if np.asarray(i).ndim == 3 else np.asarray(i) for i in (original_index, edited_index))
    if a.shape != b.shape:
        raise ValueError(f"edited index image is {b.shape[1]}×{b.shape[0]}, the original {a.shape[1]}×{a.shape[0]}")
    K = len(next(iter(palette.values())))
    changed = a != b
    if (b[changed] >= K).any():
        bad = sorted(set(b[changed][b[changed] >= K].tolist()))[:5]
        raise ValueError(f"edited index image uses entries {bad} beyond the palette's {K}")
    out = {}
    for name, v in params.items():
        v = np.array(v, copy=True)
        v[changed] = np.asarray(palette[name])[b[changed].astype(np.int64)]
        out[name] = v
    return out, changed


def read_palette(url: str) -> tuple[np.ndarray, dict]:
    """``(index (V, U) uint8, palette {name: (K, C)})`` from the files ``write_files`` wrote under ``url``."""
    import fsspec

    with fsspec.open(join(url, "palette.json")) as f:
        desc = json.load(f)
    index = read_png(join(url, "index.png"))
    return (index[..., 0] if index.ndim == 3 else index), {k: np.asarray(v, np.float64) for k, v in desc["palette"].items()}


def _take_block(index, pal):
    return pal[index[..., 0].astype(np.int64)]


class PaletteQuantizer:
    """K ≤ 256 representative BRDFs clustered in sampled-BRDF space; an index PNG and the palette."""

    params = PALETTE

    def __init__(self, *, k: int = 256, directions: int = 12, seed: int = 0):
        self.k, self.directions, self.seed = k, directions, seed

    def prepare(self, params, model) -> dict:
        """Every texel's parameters: the clustering is global, so ``encode`` needs them all concrete."""
        import dask.array as da

        return {p.name: da.asarray(params[p.name]) for p in model.parameters}

    def encode(self, params, model, prepared=None) -> Encoded:
        import dask.array as da

        names = [p.name for p in model.parameters]
        if prepared is None:  # called directly, outside a Quantize node
            prepared = dict(zip(names, da.compute(*(da.asarray(params[n]) for n in names))))
        arrays = {n: np.asarray(prepared[n], np.float64) for n in names}
        V, U = arrays[names[0]].shape[:2]
        flat = {n: a.reshape(V * U, -1) for n, a in arrays.items()}
        index, palette, _ = build_palette(model, flat, self.k, self.directions, self.seed)
        chunks = da.asarray(params[names[0]]).chunks[:2]
        enc = Encoded()
        enc.textures["index"] = da.from_array(index.reshape(V, U, 1), chunks=chunks + (1,))
        enc.scale["index"], enc.bias["index"] = np.ones(1), np.zeros(1)
        for n, p in palette.items():
            enc.textures[f"palette/{n}"] = da.from_array(p[None])
            enc.scale[f"palette/{n}"], enc.bias[f"palette/{n}"] = np.ones(p.shape[-1]), np.zeros(p.shape[-1])
        return enc

    def decode(self, textures, scale, bias, model):
        index = textures["index"]
        out = {}
        for p in model.parameters:
            pal = np.asarray(textures[f"palette/{p.name}"])[0].astype(np.float64)
            if hasattr(index, "map_blocks"):
                out[p.name] = index.map_blocks(_take_block, pal, dtype=np.float64,
                                               chunks=index.chunks[:2] + ((pal.shape[-1],),))
            else:
                out[p.name] = _take_block(np.asarray(index), pal)
        return out

    def bytes_per_texel(self, textures):
        """One index byte per texel; the palette is shared (its size is amortised, reported separately)."""
        return 1

    def write_files(self, art, textures, scale, bias, model):
        index = textures["index"][..., 0]
        write_png(join(art.url, "index.png"), index)
        palette = {k.split("/", 1)[1]: v[0].tolist() for k, v in textures.items() if k.startswith("palette/")}
        import fsspec

        with fsspec.open(join(art.url, "palette.json"), "w") as f:
            json.dump({"format": "sbrdf-palette/1", "model": model.name, "model_config": art.attrs.get("model_config", {}),
                       "entries": len(next(iter(palette.values()))), "palette": palette}, f)
        pal_bytes = sum(np.asarray(v).size * 4 for v in palette.values())
        return {"files": ["index.png", "palette.json"], "palette_entries": len(next(iter(palette.values()))),
                "palette_bytes": int(pal_bytes)}
