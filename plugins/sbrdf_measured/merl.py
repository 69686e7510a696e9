"""The MERL BRDF binary format (Matusik et al. 2003, "A Data-Driven Reflectance Model"): read, write, look up.

Format, as MERL's published reader ``BRDFRead.cpp`` reads it (little-endian):

- a header of three ``int32``: the table's dimensions ``(n_θh, n_θd, n_φd)`` = ``(90, 90, 180)``;
- ``3 · n`` ``float64`` (n = n_θh · n_θd · n_φd): the red, green and blue blocks one after the other, each
  indexed ``φd + n_φd · (θd + n_θd · θh)`` (φd fastest);
- f_r = stored value × scale, with scale 1/1500, 1.15/1500, 1.66/1500 for R, G, B (``RED_SCALE`` ...);
  a negative value is a missing entry (the reference prints "Below horizon").

Indices (``BRDFRead.cpp``):

- θh: non-linear, ``i = ⌊sqrt(θh / (π/2) · 90 · 90)⌋`` clamped to [0, 89] (θh ≤ 0 gives 0): entry i starts at
  θh = (i / 90)² · 90°, dense near the specular peak;
- θd: ``j = ⌊θd / (π/2) · 90⌋`` clamped to [0, 89];
- φd: ``φd < 0 → φd + π`` (reciprocity: f is unchanged by φd → φd + π), then ``k = ⌊φd / π · 180⌋`` clamped
  to [0, 179].

θh, θd, φd are Rusinkiewicz's half/difference angles: h = (ω_i + ω_o)/|ω_i + ω_o|, and d is ω_i rotated by
−φh about the normal and −θh about the binormal (the reference's ``std_coords_to_half_diff_coords``).  Here
they are computed from h and d = ω_i − ω_o, which is the same thing (ω_i − ω_o is twice ω_i's component
perpendicular to h) and is exactly symmetric in ω_i, ω_o: the lookups are exactly reciprocal.

Two lookups: ``nearest`` is the reference's (the indices above); ``trilinear`` treats entry (i, j, k) as the
value at the start of its bin, θh = (i/n_θh)² · 90°, θd = j/n_θd · 90°, φd = k/n_φd · 180° (so both agree at
those nodes), interpolates linearly in the index coordinates sqrt(θh/(π/2))·n_θh, θd/(π/2)·n_θd, φd/π·n_φd,
clamps θh and θd at the last node and wraps φd (period π).  Missing entries are left out of the blend
(the weights of the measured corners are renormalised; no measured corner gives 0).

Files with other header dimensions (a reduced-resolution table) are read with the same mappings scaled to
their dimensions; the MERL database's files are all 90 × 90 × 180.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sbrdf_core import input_files

from .declarations import MERL_DIMS

#: f_r = stored · SCALE[c] (BRDFRead.cpp's RED_SCALE, GREEN_SCALE, BLUE_SCALE).
SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
HALF_PI = 0.5 * np.pi


class MerlError(ValueError):
    """A file that is not a MERL table; the message names the file."""


@dataclass
class MerlTable:
    """A MERL table in memory: ``f_r (n_θh, n_θd, n_φd, 3)`` float64 sr⁻¹, 0 where ``measured`` is False."""

    f_r: np.ndarray
    measured: np.ndarray
    source: str = "<memory>"

    @property
    def dims(self) -> tuple[int, int, int]:
        n_th, n_td, n_pd = self.f_r.shape[:3]
        return int(n_th), int(n_td), int(n_pd)

    # -- lookups ---------------------------------------------------------------------------------------------

    def lookup(self, wi: np.ndarray, wo: np.ndarray, interpolation: str = "trilinear") -> tuple[np.ndarray, np.ndarray]:
        """``(f_r (..., 3), measured (...))`` at direction pairs ``(..., 3)``; 0 and False below the horizon."""
        shape = wi.shape[:-1]
        wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        z = np.array([0.0, 0.0, 1.0])
        th, td, pd = half_diff(np.where(up[:, None], wi, z), np.where(up[:, None], wo, z))
        if interpolation == "nearest":
            i, j, k = nearest_indices(th, td, pd, self.dims)
            f, ok = self.f_r[i, j, k], self.measured[i, j, k]
        elif interpolation == "trilinear":
            f, ok = self._trilinear(th, td, pd)
        else:
            raise ValueError(f"interpolation {interpolation!r}: choose nearest or trilinear")
        ok = ok & up
        f = np.where(ok[:, None], f, 0.0)
        return f.reshape(shape + (3,)), ok.reshape(shape)

    def _trilinear(self, th, td, pd):
        n_th, n_td, n_pd = self.dims
        u = np.clip(np.sqrt(th / HALF_PI) * n_th, 0.0, n_th - 1)
        v = np.clip(td / HALF_PI * n_td, 0.0, n_td - 1)
        w = pd / np.pi * n_pd
        i0 = np.minimum(np.floor(u).astype(np.int64), n_th - 1)
        j0 = np.minimum(np.floor(v).astype(np.int64), n_td - 1)
        k0 = np.floor(w).astype(np.int64)
        fu, fv, fw = u - i0, v - j0, w - k0
        i1, j1 = np.minimum(i0 + 1, n_th - 1), np.minimum(j0 + 1, n_td - 1)
        k0 = k0 % n_pd
        k1 = (k0 + 1) % n_pd
        acc = np.zeros(th.shape + (3,))
        wsum = np.zeros(th.shape)
        for ii, wu in ((i0, 1 - fu), (i1, fu)):
            for jj, wv in ((j0, 1 - fv), (j1, fv)):
                for kk, ww in ((k0, 1 - fw), (k1, fw)):
                    wt = wu * wv * ww * self.measured[ii, jj, kk]
                    acc += wt[:, None] * self.f_r[ii, jj, kk]
                    wsum += wt
        ok = wsum > 0
        return acc / np.where(ok, wsum, 1.0)[:, None], ok

    # -- the table's own bins --------------------------------------------------------------------------------

    def node_directions(self, stride=(1, 1, 1)) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]]:
        """``(wi, wo, (i, j, k))``: the direction pair of every ``stride``-th entry (φh = 0), flattened."""
        n_th, n_td, n_pd = self.dims
        grids = np.meshgrid(np.arange(0, n_th, stride[0]), np.arange(0, n_td, stride[1]),
                            np.arange(0, n_pd, stride[2]), indexing="ij")
        i, j, k = (g.ravel() for g in grids)
        th, td, pd = node_angles(i, j, k, self.dims)
        wi, wo = half_diff_to_directions(th, td, pd)
        return wi, wo, (i, j, k)


# -- angles ----------------------------------------------------------------------------------------------------


def half_diff(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rusinkiewicz angles ``(θh, θd, φd)`` of unit direction pairs ``(N, 3)``, φd folded into [0, π).

    Exactly symmetric in ``wi`` and ``wo``.  Pairs must not be opposite (wi + wo = 0).
    """
    s = wi + wo
    ls = np.linalg.norm(s, axis=-1)
    h = s / ls[:, None]
    r = np.hypot(h[:, 0], h[:, 1])
    th = np.arctan2(r, h[:, 2])
    pos = r > 0
    rr = np.where(pos, r, 1.0)
    c, sn = np.where(pos, h[:, 0] / rr, 1.0), np.where(pos, h[:, 1] / rr, 0.0)
    d = wi - wo
    td = np.arctan2(np.linalg.norm(d, axis=-1), ls)
    x = d[:, 0] * h[:, 2] * c + d[:, 1] * h[:, 2] * sn - d[:, 2] * r  # d · t, t = (cos θh cos φh, cos θh sin φh, −sin θh)
    y = -d[:, 0] * sn + d[:, 1] * c  # d · b, b = (−sin φh, cos φh, 0)
    flip = (y < 0) | ((y == 0) & (x < 0))
    x, y = np.where(flip, -x, x), np.where(flip, -y, y)
    pd = np.arctan2(y, x)
    pd = np.where(pd >= np.pi, 0.0, pd)
    return th, td, pd


def half_diff_to_directions(th, td, pd, ph=0.0) -> tuple[np.ndarray, np.ndarray]:
    """The inverse: ``(wi, wo)`` ``(N, 3)`` for half/difference angles (ω_o is ω_i mirrored about h)."""
    th, td, pd = (np.asarray(a, np.float64) for a in (th, td, pd))
    ph = np.broadcast_to(np.asarray(ph, np.float64), th.shape)
    d = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], axis=-1)
    ct, st, cp, sp = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph)
    t = np.stack([ct * cp, ct * sp, -st], axis=-1)
    b = np.stack([-sp, cp, np.zeros_like(sp)], axis=-1)
    h = np.stack([st * cp, st * sp, ct], axis=-1)
    wi = d[..., :1] * t + d[..., 1:2] * b + d[..., 2:] * h
    wo = 2 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


def node_angles(i, j, k, dims=MERL_DIMS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles of entry (i, j, k): the start of its bin (where BRDFRead.cpp's lookup begins returning it)."""
    n_th, n_td, n_pd = dims
    return ((np.asarray(i) / n_th) ** 2 * HALF_PI, np.asarray(j) / n_td * HALF_PI, np.asarray(k) / n_pd * np.pi)


def nearest_indices(th, td, pd, dims=MERL_DIMS):
    """BRDFRead.cpp's ``theta_half_index``, ``theta_diff_index``, ``phi_diff_index`` (φd already in [0, π))."""
    n_th, n_td, n_pd = dims
    i = np.where(th <= 0, 0, np.floor(np.sqrt(np.maximum(th, 0) / HALF_PI * n_th * n_th))).astype(np.int64)
    j = np.floor(td / HALF_PI * n_td).astype(np.int64)
    k = np.floor(np.where(pd < 0, pd + np.pi, pd) / np.pi * n_pd).astype(np.int64)
    return np.clip(i, 0, n_th - 1), np.clip(j, 0, n_td - 1), np.clip(k, 0, n_pd - 1)


# -- files -----------------------------------------------------------------------------------------------------


def read_merl(path: str | os.PathLike) -> MerlTable:
    """Read a MERL ``.binary`` file; a wrong size or header is a :class:`MerlError` naming the file."""
    path = Path(path)
    try:
        raw = input_files.read_bytes(path)  # regular files only, bounded: never /dev/zero read whole
    except FileNotFoundError:
        raise MerlError(f"{path}: no such MERL file") from None
    except OSError as e:
        raise MerlError(f"{path}: cannot read the MERL file: {e.strerror}") from None
    if len(raw) < 12:
        raise MerlError(f"{path}: {len(raw)} bytes, shorter than the MERL header (three int32 dimensions)")
    dims = tuple(int(n) for n in np.frombuffer(raw, "<i4", 3))
    if any(n <= 0 or n > 100000 for n in dims):
        raise MerlError(f"{path}: header dimensions {dims} are not a MERL table's (90, 90, 180)")
    n = dims[0] * dims[1] * dims[2]
    want = 12 + 3 * n * 8
    if len(raw) != want:
        raise MerlError(f"{path}: {len(raw)} bytes, but a MERL table of dimensions {dims} has {want} "
                        f"(12-byte header + 3 x {n} float64)")
    data = np.frombuffer(raw, "<f8", 3 * n, offset=12).reshape(3, *dims)
    measured = (data >= 0).all(axis=0) & np.isfinite(data).all(axis=0)
    f_r = np.where(measured[None], data, 0.0) * SCALE[:, None, None, None]
    return MerlTable(np.ascontiguousarray(np.moveaxis(f_r, 0, -1)), measured, str(path))


def write_merl(path: str | os.PathLike, f_r: np.ndarray, measured: np.ndarray | None = None) -> None:
    """Write ``f_r (n_θh, n_θd, n_φd, 3)`` sr⁻¹ as a MERL file (missing entries stored as −1)."""
    f_r = np.asarray(f_r, np.float64)
    if f_r.ndim != 4 or f_r.shape[-1] != 3:
        raise ValueError(f"f_r must be (n_theta_h, n_theta_d, n_phi_d, 3), got {f_r.shape}")
    measured = np.isfinite(f_r).all(axis=-1) if measured is None else np.asarray(measured, bool)
    data = np.moveaxis(f_r, -1, 0) / SCALE[:, None, None, None]
    data = np.where(measured[None], data, -1.0)
    with open(path, "wb") as f:
        f.write(np.asarray(f_r.shape[:3], "<i4").tobytes())
        f.write(np.ascontiguousarray(data, "<f8").tobytes())


def tabulate(model, params: dict, dims=MERL_DIMS, theta_h_range: tuple[int, int] | None = None):
    """``(f_r, measured)`` of a BRDF model with one parameter set at the table's nodes (rows ``theta_h_range``).

    Entries whose node direction pair is below the horizon are missing, as in the database.
    """
    n_th, n_td, n_pd = dims
    lo, hi = theta_h_range or (0, n_th)
    i, j, k = np.meshgrid(np.arange(lo, hi), np.arange(n_td), np.arange(n_pd), indexing="ij")
    wi, wo = half_diff_to_directions(*node_angles(i.ravel(), j.ravel(), k.ravel(), dims))
    up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    p = {name: np.asarray(v, np.float64).reshape(1, -1) for name, v in params.items()}
    f = np.zeros((len(wi), 3))
    if up.any():
        f[up] = model.eval(p, wi[up][None], wo[up][None])[0]
    shape = (hi - lo, n_td, n_pd)
    return f.reshape(shape + (3,)), up.reshape(shape)


_CACHE: dict = {}


def load_cached(path: str) -> MerlTable:
    """:func:`read_merl`, cached per process by path, size and modification time (models are re-created often)."""
    st = os.stat(path)
    key = (os.path.abspath(path), st.st_size, st.st_mtime_ns)
    table = _CACHE.get(key)
    if table is None:
        if len(_CACHE) >= 4:
            _CACHE.clear()
        table = _CACHE[key] = read_merl(path)
    return table


__all__ = ["MERL_DIMS", "SCALE", "MerlError", "MerlTable", "half_diff", "half_diff_to_directions", "load_cached",
           "nearest_indices", "node_angles", "read_merl", "tabulate", "write_merl"]
