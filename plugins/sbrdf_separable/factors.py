"""Factor textures of a separable BRDF: what they hold, how they are looked up, how they are stored.

``g`` and ``h`` are ``(N, K, K, 3)``: N terms, K×K texels (row = v, column = u,
texel centres at ((j + 0.5)/K, (i + 0.5)/K)), linear RGB, and
f_r(ω_i, ω_o) ≈ Σ_k g_k(x) h_k(y) per channel, looked up bilinearly exactly
as OpenGL's ``GL_LINEAR`` does (clamp-to-edge, or repeat on periodic axes).

Storage (``SeparableFactors`` zarr group, version 1): arrays ``g``, ``h``
(float32 or float16, or uint8 with per-term, per-channel ``g_scale``,
``g_bias``, ``h_scale``, ``h_bias`` decoding ``value = code/255 · scale +
bias``: §6.1's biasing, which turns the negative values of later terms into
textures of unsigned bytes) and attributes naming the parameterization, the
method and its settings.  A store is written under a temporary name and
renamed when complete, so a reader never sees a half-written one.  Only a
``SeparableFactors`` store is ever replaced: any other file or directory at the
path (a symbolic link, a store root, an artifact) is an error naming it, and
nothing is removed (:func:`check_target`).
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from dataclasses import dataclass, field
from typing import Any

import numpy as np

KIND, VERSION = "SeparableFactors", 1
ENCODINGS = ("float32", "float16", "unorm8")


def bilinear(tex: np.ndarray, uv: np.ndarray, wrap: tuple[bool, bool] = (False, False)) -> np.ndarray:
    """``GL_LINEAR`` lookup of ``tex (N, K, K, C)`` at ``uv (S, 2)`` -> ``(N, S, C)``."""
    N, H, W, C = tex.shape
    uv = np.nan_to_num(np.asarray(uv, float), nan=0.5)
    out_idx, frac = [], []
    for axis, size in ((0, W), (1, H)):
        s = uv[:, axis] * size - 0.5
        i0 = np.floor(s)
        f = s - i0
        i0 = i0.astype(np.int64)
        i1 = i0 + 1
        if wrap[axis]:
            i0, i1 = np.mod(i0, size), np.mod(i1, size)
        else:
            i0, i1 = np.clip(i0, 0, size - 1), np.clip(i1, 0, size - 1)
        out_idx.append((i0, i1))
        frac.append(f[None, :, None])
    (u0, u1), (v0, v1) = out_idx
    fu, fv = frac
    top = tex[:, v0, u0] * (1 - fu) + tex[:, v0, u1] * fu
    bottom = tex[:, v1, u0] * (1 - fu) + tex[:, v1, u1] * fu
    return top * (1 - fv) + bottom * fv


def cell_centres(size: int) -> np.ndarray:
    """Texture coordinates of the K² texel centres, row-major (v, u) order, ``(K², 2)`` as (u, v)."""
    c = (np.arange(size) + 0.5) / size
    v, u = np.meshgrid(c, c, indexing="ij")
    return np.stack([u.ravel(), v.ravel()], axis=-1)


@dataclass
class Factors:
    """A separable approximation: factor textures plus how they were made."""

    g: np.ndarray  # (N, K, K, 3) decoded values
    h: np.ndarray
    parameterization: str
    parameterization_config: dict
    meta: dict = field(default_factory=dict)

    @property
    def terms(self) -> int:
        return self.g.shape[0]

    @property
    def size(self) -> int:
        return self.g.shape[1]

    def truncated(self, terms: int) -> Factors:
        return Factors(self.g[:terms], self.h[:terms], self.parameterization, dict(self.parameterization_config),
                       {**self.meta, "terms": terms})

    def encoded(self, encoding: str) -> Factors:
        """The factors as they decode after storing with ``encoding`` (what a renderer would see)."""
        if encoding == "float32":
            return self
        if encoding == "float16":
            return Factors(self.g.astype(np.float16).astype(np.float64), self.h.astype(np.float16).astype(np.float64),
                           self.parameterization, self.parameterization_config, self.meta)
        g = _decode(*_encode8(self.g))
        h = _decode(*_encode8(self.h))
        return Factors(g, h, self.parameterization, self.parameterization_config, self.meta)


def _encode8(a: np.ndarray):
    """Per term and channel: bias = min, scale = max − min; codes in 0..255."""
    lo = a.min(axis=(1, 2))
    hi = a.max(axis=(1, 2))
    scale = np.where(hi > lo, hi - lo, 1.0)
    code = np.rint((a - lo[:, None, None, :]) / scale[:, None, None, :] * 255.0)
    return np.clip(code, 0, 255).astype(np.uint8), scale, lo


def _decode(code, scale, bias):
    return code.astype(np.float64) / 255.0 * scale[:, None, None, :] + bias[:, None, None, :]


def save(factors: Factors, url: str, encoding: str = "float32") -> str:
    """Write ``factors`` as a ``SeparableFactors`` store at ``url`` (a local path), atomically; returns the path."""
    import zarr

    if encoding not in ENCODINGS:
        raise ValueError(f"encoding {encoding!r}: expected one of {list(ENCODINGS)}")
    if not (np.isfinite(factors.g).all() and np.isfinite(factors.h).all()):
        raise ValueError(f"separable factors for {url!r} contain non-finite values; not writing them")
    path = os.path.abspath(os.path.expanduser(url))
    check_target(path)
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    tmp = f"{path}.tmp-{uuid.uuid4().hex[:8]}"
    group = zarr.open_group(store=tmp, mode="w")
    for name, a in (("g", factors.g), ("h", factors.h)):
        if encoding == "unorm8":
            code, scale, bias = _encode8(a)
            group.create_array(name, data=code, chunks=code.shape)
            group.create_array(f"{name}_scale", data=scale.astype(np.float64))
            group.create_array(f"{name}_bias", data=bias.astype(np.float64))
        else:
            data = a.astype(encoding)
            group.create_array(name, data=data, chunks=data.shape)
    group.attrs.update(json.loads(json.dumps({
        "kind": KIND, "version": VERSION, "encoding": encoding, "terms": factors.terms, "size": factors.size,
        "parameterization": factors.parameterization, "parameterization_config": factors.parameterization_config,
        **factors.meta,
    }, default=float)))
    old = f"{path}.old-{uuid.uuid4().hex[:8]}"
    try:
        check_target(path)  # again: something may have appeared there while the arrays were written
    except Exception:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if os.path.lexists(path):
        os.rename(path, old)
    os.rename(tmp, path)
    shutil.rmtree(old, ignore_errors=True)
    return path


def is_factors_store(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a directory holding a ``SeparableFactors`` group (what :func:`save` writes)."""
    try:
        with open(os.path.join(path, "zarr.json"), "rb") as f:
            meta = json.loads(f.read(1 << 20))
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and isinstance(meta.get("attributes"), dict) and meta["attributes"].get("kind") == KIND


def check_target(path: str | os.PathLike) -> None:
    """Refuse (``OutputPathError`` naming ``path``) to write factors where :func:`save` would replace anything
    but a ``SeparableFactors`` store: a file, a foreign directory, a symbolic link, a store root, an artifact."""
    from sbrdf_core.outputs import check_replaceable

    check_replaceable(path, is_factors_store, f"a {KIND} store")


def load(url: str) -> Factors:
    """Read a ``SeparableFactors`` store; errors name the path."""
    import zarr

    try:
        group = zarr.open_group(store=url, mode="r")
        attrs: dict[str, Any] = dict(group.attrs)  # JSON, checked below
    except Exception as e:
        raise FileNotFoundError(f"separable factors {url!r}: cannot open ({type(e).__name__}: {e}); "
                                "re-run the fit that writes them") from None
    if attrs.get("kind") != KIND:
        raise ValueError(f"{url!r} is not a {KIND} store (kind {attrs.get('kind')!r})")
    if attrs.get("version") != VERSION:
        raise ValueError(f"{url!r}: {KIND} version {attrs.get('version')!r}, this code reads {VERSION}")
    def read(name: str) -> np.ndarray:
        a = group[name]
        if not isinstance(a, zarr.Array):
            raise ValueError(f"{url!r}: {name!r} is a group, not an array; re-run the fit that writes the factors")
        return np.asarray(a[...])

    out = {}
    for name in ("g", "h"):
        a = read(name)
        if attrs["encoding"] == "unorm8":
            a = _decode(a, read(f"{name}_scale"), read(f"{name}_bias"))
        out[name] = np.asarray(a, np.float64)
    meta = {k: v for k, v in attrs.items() if k not in ("kind", "version", "parameterization", "parameterization_config")}
    return Factors(out["g"], out["h"], attrs["parameterization"], dict(attrs.get("parameterization_config", {})), meta)
