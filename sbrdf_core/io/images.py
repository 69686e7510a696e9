"""OpenEXR (linear float RGB) and PNG (8-bit sRGB) files, local or on any fsspec URL."""

from __future__ import annotations

import os
import tempfile

import numpy as np


def _url_to_fs(url: str):
    import fsspec  # on first use: node kinds import this module while a graph is only validated

    return fsspec.core.url_to_fs(url)


def linear_to_srgb8(image: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (IEC 61966-2-1 transfer curve), NaN as black."""
    x = np.nan_to_num(np.asarray(image, np.float64) * exposure, nan=0.0, posinf=1.0, neginf=0.0)
    x = np.clip(x, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255).astype(np.uint8)


def _is_local(fs) -> bool:
    from fsspec.implementations.local import LocalFileSystem

    return isinstance(fs, LocalFileSystem)


def _put(url: str, write_local) -> None:
    fs, path = _url_to_fs(url)
    if _is_local(fs):
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
        write_local(path)
        return
    with tempfile.TemporaryDirectory() as d:
        local = os.path.join(d, os.path.basename(path))
        write_local(local)
        fs.put_file(local, path)


def write_exr(url: str, image: np.ndarray) -> None:
    """Write ``(H, W, 3)`` linear float32 RGB as a ZIP-compressed OpenEXR file."""
    import OpenEXR

    rgb = np.ascontiguousarray(np.asarray(image, np.float32)[..., :3])
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    _put(url, lambda p: OpenEXR.File(header, {"RGB": rgb}).write(p))


#: Most pixels :func:`read_exr` decodes (a 16k x 16k image): a header claiming more is refused before its
#: pixels are read, so a small hostile file cannot make the reader allocate gigabytes.
MAX_PIXELS = 1 << 28


def read_exr(url: str, max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """Read an OpenEXR file's RGB (or R, G, B, or Y) channels as ``(H, W, 3)`` float32.

    The header is read first: an image of more than ``max_pixels`` pixels is a ``ValueError`` naming its size.
    """
    import OpenEXR

    fs, path = _url_to_fs(url)
    with tempfile.TemporaryDirectory() as d:
        local = path if _is_local(fs) else os.path.join(d, "x.exr")
        if local != path:
            fs.get_file(path, local)
        with OpenEXR.File(local, header_only=True) as f:
            (x0, y0), (x1, y1) = f.header()["dataWindow"]
        width, height = int(x1) - int(x0) + 1, int(y1) - int(y0) + 1
        if width <= 0 or height <= 0 or width * height > max_pixels:
            raise ValueError(f"{url}: the header says {width}x{height} pixels, more than the {max_pixels} this "
                             f"reader decodes; not decoded")
        with OpenEXR.File(local) as f:
            ch = f.channels()
            if "RGB" in ch:
                return np.asarray(ch["RGB"].pixels, np.float32)
            if all(c in ch for c in "RGB"):
                return np.stack([np.asarray(ch[c].pixels, np.float32) for c in "RGB"], axis=-1)
            if "Y" in ch:
                y = np.asarray(ch["Y"].pixels, np.float32)
                return np.repeat(y[..., None], 3, axis=-1)
            raise ValueError(f"{url}: no RGB or Y channels (has {sorted(ch)})")


def write_png(url: str, image: np.ndarray) -> None:
    """Write an 8- or 16-bit RGB(A) array as PNG."""
    import cv2

    img = np.asarray(image)
    if img.ndim == 3 and img.shape[-1] in (3, 4):
        img = img[..., [2, 1, 0, 3][: img.shape[-1]]]  # OpenCV stores BGR(A)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError(f"cannot encode PNG for {url}")
    _put(url, lambda p: open(p, "wb").write(buf.tobytes()))


def read_png(url: str) -> np.ndarray:
    """Read a PNG as RGB(A) at its stored bit depth."""
    import cv2
    import fsspec

    with fsspec.open(url, "rb") as f:
        data = np.frombuffer(f.read(), np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{url} is not a readable image")
    if img.ndim == 3:
        img = img[..., [2, 1, 0, 3][: img.shape[-1]]]
    return img


def write_exr_channels(url: str, channels: dict, attributes: dict | None = None) -> None:
    """Write named ``(H, W)`` channels (float32 -> FLOAT, float16 -> HALF) as one ZIP-compressed EXR.

    For multi-channel material files (``rho_d.R``, ``rho_s_1.G``, ``exponent_1``): every
    parameter of a texel in one file, each channel at its own precision.  ``attributes``
    are string header attributes (a JSON description, the colour space).
    """
    import OpenEXR

    chans = {}
    for name, a in channels.items():
        a = np.asarray(a)
        if a.ndim != 2:
            raise ValueError(f"{url}: channel {name!r} must be (H, W), got {a.shape}")
        if a.dtype not in (np.float16, np.float32):
            a = a.astype(np.float32)
        chans[name] = np.ascontiguousarray(a)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update({k: str(v) for k, v in (attributes or {}).items()})
    _put(url, lambda p: OpenEXR.File(header, chans).write(p))


def read_exr_channels(url: str) -> tuple[dict, dict]:
    """Every channel of an EXR as ``name -> (H, W)`` array at its stored precision, plus the header."""
    import OpenEXR

    fs, path = _url_to_fs(url)
    with tempfile.TemporaryDirectory() as d:
        local = path if _is_local(fs) else os.path.join(d, "x.exr")
        if local != path:
            fs.get_file(path, local)
        with OpenEXR.File(local, separate_channels=True) as f:
            chans = {k: np.array(c.pixels) for k, c in f.channels().items()}
            header = dict(f.header())
    return chans, header
