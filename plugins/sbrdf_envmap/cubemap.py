"""Cube maps with MIP chains: loading EXR environments, addressing, filtering (NumPy and GLSL, the same rules).

Directions are world directions (+z up, as in scene files).  Faces follow
OpenGL's cube-map convention (order +X, −X, +Y, −Y, +Z, −Z; the major axis
picks the face, ``(s, t)`` from the other two components), so a map
authored for GL reads the same here.  Each face is ``(S, S, 3)`` with row
``j`` at ``t = (j + ½)/S``.

Filtering is per face, clamp-to-edge bilinear, and linear between two MIP
levels; the GL renderer stores the six faces side by side in one 2D texture
(``6S × S``, level ``L`` is ``6S/2^L × S/2^L``) so that it can upload every
level it computed (prefiltered maps, whose levels are not box averages) and
fetch exactly what the NumPy reference fetches.  Faces do not blend across
their edges (McAllister and Mühlbacher do not discuss seams); at the sizes
used here the seam error is below the prefiltering error.

Lat-long maps: ``u = φ/2π`` with ``φ = atan2(y, x)`` (wrapping), ``v = θ/π``
with θ from +z; row 0 is the zenith.  Cube EXR files hold the six faces in
the order above stacked vertically (``H = 6W``) or side by side (``W = 6H``),
each face's row 0 at ``t = 0``.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError

FACES = 6


def face_st(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Face index, ``s``, ``t`` in [0, 1] and ``|major axis|`` of directions ``(R, 3)`` (need not be unit)."""
    d = np.asarray(d, np.float64)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    ax, ay, az = np.abs(x), np.abs(y), np.abs(z)
    xmaj = (ax >= ay) & (ax >= az)
    ymaj = ~xmaj & (ay >= az)
    face = np.where(xmaj, np.where(x >= 0, 0, 1), np.where(ymaj, np.where(y >= 0, 2, 3), np.where(z >= 0, 4, 5)))
    ma = np.where(xmaj, ax, np.where(ymaj, ay, az))
    sc = np.select([face == 0, face == 1, face == 2, face == 3, face == 4], [-z, z, x, x, x], -x)
    tc = np.select([face == 0, face == 1, face == 2, face == 3, face == 4], [-y, -y, z, -z, -y], -y)
    ma_safe = np.maximum(ma, 1e-300)
    return face, (sc / ma_safe + 1) / 2, (tc / ma_safe + 1) / 2, ma


def face_directions(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions ``(6, S, S, 3)`` through the texel centres and each texel's solid angle ``(6, S, S)``."""
    c = (np.arange(size) + 0.5) / size * 2 - 1
    b, a = np.meshgrid(c, c, indexing="ij")  # b: t (rows), a: s (columns)
    one = np.ones_like(a)
    # inverse of face_st: (sc, tc, ma) -> direction, per face
    dirs = np.stack([
        np.stack([one, -b, -a], -1), np.stack([-one, -b, a], -1),
        np.stack([a, one, b], -1), np.stack([a, -one, -b], -1),
        np.stack([a, -b, one], -1), np.stack([-a, -b, -one], -1),
    ])
    e = np.arange(size + 1) / size * 2 - 1  # texel edges
    area = lambda x, y: np.arctan2(x * y, np.sqrt(x * x + y * y + 1))  # noqa: E731  (exact texel solid angle)
    y0, x0 = np.meshgrid(e[:-1], e[:-1], indexing="ij")
    y1, x1 = np.meshgrid(e[1:], e[1:], indexing="ij")
    solid = area(x1, y1) - area(x0, y1) - area(x1, y0) + area(x0, y0)
    return dirs / np.linalg.norm(dirs, axis=-1, keepdims=True), np.broadcast_to(solid, (FACES, size, size)).copy()


def latlong_lookup(image: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Bilinear look-up of a lat-long map ``(H, W, 3)`` in unit directions ``(R, 3)``: wraps in u, clamps in v."""
    H, W = image.shape[:2]
    u = np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi) % 1.0
    v = np.arccos(np.clip(d[:, 2], -1, 1)) / np.pi
    x, y = u * W - 0.5, np.clip(v * H - 0.5, 0, H - 1)
    i0, j0 = np.floor(x).astype(np.int64), np.minimum(np.floor(y).astype(np.int64), H - 1)
    fx, fy = (x - i0)[:, None], (y - j0)[:, None]
    i1, j1 = (i0 + 1) % W, np.minimum(j0 + 1, H - 1)
    i0 %= W
    m = image.astype(np.float64)
    return (1 - fy) * ((1 - fx) * m[j0, i0] + fx * m[j0, i1]) + fy * ((1 - fx) * m[j1, i0] + fx * m[j1, i1])


def latlong_to_cube(image: np.ndarray, size: int, supersample: int = 4) -> np.ndarray:
    """Resample a lat-long map onto cube faces ``(6, S, S, 3)``, averaging ``supersample²`` look-ups per texel."""
    fine, _ = face_directions(size * supersample)
    vals = latlong_lookup(image, fine.reshape(-1, 3)).reshape(FACES, size, supersample, size, supersample, 3)
    return vals.mean(axis=(2, 4))


def cube_from_exr_image(image: np.ndarray, file: str) -> np.ndarray:
    """A cube EXR's pixels (faces stacked vertically or side by side) as ``(6, S, S, 3)``."""
    H, W = image.shape[:2]
    if H == 6 * W:
        return image.reshape(FACES, W, W, 3)
    if W == 6 * H:
        return image.reshape(H, FACES, H, 3).transpose(1, 0, 2, 3)
    raise SbrdfError(f"{file}: a cube environment map must hold six square faces stacked vertically (H = 6W) or "
                     f"side by side (W = 6H); got {W}×{H}")


def resample_cube(faces: np.ndarray, size: int) -> np.ndarray:
    """Cube faces at another power-of-two size: box averages going down, bilinear look-ups going up."""
    S = faces.shape[1]
    if S == size:
        return faces
    if S > size and S % size == 0:
        k = S // size
        return faces.reshape(FACES, size, k, size, k, 3).mean(axis=(2, 4))
    d, _ = face_directions(size)
    return sample(faces, d.reshape(-1, 3)).reshape(FACES, size, size, 3)


def load_environment(file: str, layout: str, size: int, intensity: float = 1.0) -> np.ndarray:
    """The scene's environment as cube faces ``(6, size, size, 3)`` float64 (radiance × intensity)."""
    from sbrdf_core.input_files import check_file
    from sbrdf_core.io import read_exr

    try:
        if "://" not in str(file):
            check_file(file)  # a regular file within the size limit: OpenEXR would block on a FIFO
        image = np.asarray(read_exr(file), np.float64)
    except SbrdfError:
        raise
    except Exception as e:  # missing file, not an EXR
        raise SbrdfError(f"{file}: cannot read the environment map ({e})") from None
    if image.ndim != 3 or image.shape[2] < 3 or min(image.shape[:2]) < 1:
        raise SbrdfError(f"{file}: an environment map must be an RGB image, got shape {image.shape}")
    image = image[..., :3]
    if not np.all(np.isfinite(image)) or np.any(image < 0):
        raise SbrdfError(f"{file}: the environment map has negative, NaN or infinite radiance")
    if layout == "latlong":
        faces = latlong_to_cube(image, size)
    elif layout == "cube":
        faces = resample_cube(cube_from_exr_image(image, file), size)
    else:
        raise SbrdfError(f"{file}: unknown environment layout {layout!r}; use latlong or cube")
    return faces * intensity


def mip_chain(faces: np.ndarray) -> list[np.ndarray]:
    """Levels ``0 … log2 S`` by 2×2 box averaging, each ``(6, S/2^L, S/2^L, 3)``."""
    S = faces.shape[1]
    if S & (S - 1):
        raise SbrdfError(f"cube faces must be a power of two in size for a MIP chain, got {S}")
    levels = [np.asarray(faces, np.float64)]
    while levels[-1].shape[1] > 1:
        f = levels[-1]
        s = f.shape[1] // 2
        levels.append(f.reshape(FACES, s, 2, s, 2, 3).mean(axis=(2, 4)))
    return levels


def sample(faces: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Clamp-to-edge bilinear look-up of one level ``(6, S, S, C)`` in directions ``(R, 3)`` -> ``(R, C)``."""
    S = faces.shape[1]
    face, s, t, _ = face_st(d)
    x = np.clip(s * S - 0.5, 0, S - 1)
    y = np.clip(t * S - 0.5, 0, S - 1)
    i0, j0 = np.minimum(np.floor(x).astype(np.int64), S - 1), np.minimum(np.floor(y).astype(np.int64), S - 1)
    i1, j1 = np.minimum(i0 + 1, S - 1), np.minimum(j0 + 1, S - 1)
    fx, fy = (x - i0)[:, None], (y - j0)[:, None]
    f = faces
    return ((1 - fy) * ((1 - fx) * f[face, j0, i0] + fx * f[face, j0, i1])
            + fy * ((1 - fx) * f[face, j1, i0] + fx * f[face, j1, i1]))


def sample_lod(levels: list[np.ndarray], d: np.ndarray, lod: np.ndarray | float) -> np.ndarray:
    """Trilinear look-up: bilinear in levels ⌊lod⌋ and ⌊lod⌋+1, linear between; ``lod`` clamped to the chain."""
    lod = np.clip(np.broadcast_to(np.asarray(lod, np.float64), (len(d),)), 0, len(levels) - 1)
    l0 = np.minimum(np.floor(lod).astype(np.int64), len(levels) - 1)
    frac = lod - l0
    out = np.zeros((len(d), levels[0].shape[-1]))
    for L in np.unique(l0):
        sel = l0 == L
        a = sample(levels[L], d[sel])
        if L + 1 < len(levels):
            f = frac[sel][:, None]
            nz = f[:, 0] > 0
            if nz.any():
                a[nz] = (1 - f[nz]) * a[nz] + f[nz] * sample(levels[L + 1], d[sel][nz])
        out[sel] = a
    return out


def atlas(levels: list[np.ndarray]) -> list[np.ndarray]:
    """Each level as the GL texture image ``(S_L, 6 S_L, 3)`` float32: faces side by side, row 0 at t = 0."""
    return [np.ascontiguousarray(f.transpose(1, 0, 2, 3).reshape(f.shape[1], -1, f.shape[-1]), np.float32)
            for f in levels]


#: GLSL twins of :func:`face_st`, :func:`sample` and :func:`sample_lod` over an atlas texture.
GLSL = """
vec3 cube_st(vec3 d) {  // (s, t, face) with OpenGL's cube-map rules
    vec3 a = abs(d);
    float face, sc, tc, ma;
    if (a.x >= a.y && a.x >= a.z) { ma = a.x; face = d.x >= 0.0 ? 0.0 : 1.0; sc = d.x >= 0.0 ? -d.z : d.z; tc = -d.y; }
    else if (a.y >= a.z) { ma = a.y; face = d.y >= 0.0 ? 2.0 : 3.0; sc = d.x; tc = d.y >= 0.0 ? d.z : -d.z; }
    else { ma = a.z; face = d.z >= 0.0 ? 4.0 : 5.0; sc = d.z >= 0.0 ? d.x : -d.x; tc = -d.y; }
    return vec3((sc / ma + 1.0) * 0.5, (tc / ma + 1.0) * 0.5, face);
}
vec3 atlas_level(sampler2D atlas, vec3 st, int level, float size0) {
    float S = size0 / float(1 << level);
    vec2 c = clamp(st.xy, vec2(0.5 / S), vec2(1.0 - 0.5 / S));  // clamp to the face's own texels
    return textureLod(atlas, vec2((st.z + c.x) / 6.0, c.y), float(level)).rgb;
}
vec3 atlas_lod(sampler2D atlas, vec3 d, float lod, float size0, float top) {
    vec3 st = cube_st(d);
    lod = clamp(lod, 0.0, top);
    int l0 = int(floor(lod));
    float f = lod - float(l0);
    vec3 a = atlas_level(atlas, st, l0, size0);
    if (f > 0.0) a = mix(a, atlas_level(atlas, st, l0 + 1, size0), f);
    return a;
}
"""
