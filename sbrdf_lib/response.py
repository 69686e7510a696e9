"""Camera response curves as tables: the named models and the per-channel inverse response.

Cameras do not store linear sensor values: a response curve maps the
exposure (radiance × time) to a pixel code (seed 000 §3.4.1).  Here a curve
is a table ``g: code -> relative exposure`` with one entry per code (256 or
65536), normalised so that ``g(max code) = 1``: relative exposure 1 is the
saturation point.  That is also the ``{"type": "table"}`` form of the
capture-folder manifest.

In the library layer because both sides of a capture folder use it: simulated
cameras expose with :meth:`ResponseCurve.expose`, readers linearise with
:meth:`ResponseCurve.linearize`.  Recovering a curve from brackets stays with
the reader (``sbrdf_capture.response``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sbrdf_core.errors import SbrdfError

__all__ = ["ResponseCurve", "ResponseError", "codes", "cubic_table", "gamma_table", "response_table", "srgb_table"]


class ResponseError(SbrdfError):
    """A response curve cannot be built or recovered from the given data."""


# ---------------------------------------------------------------------------
# curve models (inverse response tables, code -> relative exposure)
# ---------------------------------------------------------------------------


def codes(bits: int) -> np.ndarray:
    """Normalised codes ``z = code / max`` for every code of a ``bits``-bit camera."""
    n = 2**bits
    return np.arange(n, dtype=np.float64) / (n - 1)


def gamma_table(bits: int, gamma: float = 2.2) -> np.ndarray:
    """``g(z) = z^gamma``: a pure power law (a line in log-log space)."""
    return codes(bits) ** gamma


def srgb_table(bits: int) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) decoded: a linear toe, then a 2.4 power."""
    z = codes(bits)
    return np.where(z <= 0.04045, z / 12.92, ((z + 0.055) / 1.055) ** 2.4)


def cubic_table(bits: int, coefficients: Sequence[float]) -> np.ndarray:
    """McAllister's curve ``log X = Σ a_m (log z)^m``, m = 1..3 (natural logs); ``g(0) = 0``."""
    a1, a2, a3 = (list(coefficients) + [0.0, 0.0, 0.0])[:3]
    z = codes(bits)
    with np.errstate(divide="ignore"):
        y = np.log(z)
    with np.errstate(invalid="ignore", over="ignore"):
        out = np.exp(a1 * y + a2 * y**2 + a3 * y**3)
    out[0] = 0.0
    if np.any(np.diff(out) < 0):
        raise ResponseError(f"cubic response {coefficients} is not monotonic over the code range")
    return out


def response_table(kind: str, bits: int, gamma: float = 2.2, coefficients: Sequence[float] = (2.2, 0.0, 0.0)) -> np.ndarray:
    """A named curve: ``gamma``, ``srgb`` or ``cubic``."""
    if kind == "gamma":
        return gamma_table(bits, gamma)
    if kind == "srgb":
        return srgb_table(bits)
    if kind == "cubic":
        return cubic_table(bits, coefficients)
    raise ResponseError(f"unknown response curve {kind!r}; use gamma, srgb or cubic")


class ResponseCurve:
    """An inverse response per channel: ``table[code, channel]`` -> relative exposure.

    ``table`` may be ``(N,)`` (one curve for all channels) or ``(N, 3)``.
    """

    def __init__(self, table: np.ndarray):
        t = np.asarray(table, dtype=np.float64)
        if t.ndim == 1:
            t = np.repeat(t[:, None], 3, axis=1)
        if t.shape[0] not in (256, 65536) or t.shape[1:] != (3,):
            raise ResponseError(f"a response table needs 256 or 65536 rows and 1 or 3 channels, got {t.shape}")
        self.table = t
        self.bits = 8 if t.shape[0] == 256 else 16

    @property
    def max_code(self) -> int:
        return self.table.shape[0] - 1

    def linearize(self, image: np.ndarray) -> np.ndarray:
        """Integer codes ``(H, W, 3)`` -> relative exposure ``(H, W, 3) float32``."""
        z = np.asarray(image)
        if z.dtype.kind not in "ui" or z.max(initial=0) > self.max_code:
            raise ResponseError(f"image codes ({z.dtype}, max {z.max(initial=0)}) do not fit a {self.bits}-bit response table")
        out = np.empty(z.shape, np.float32)
        for c in range(3):
            out[..., c] = self.table[:, c].astype(np.float32)[z[..., c]]
        return out

    def expose(self, exposure: np.ndarray) -> np.ndarray:
        """The forward curve: relative exposure -> integer codes (what a camera stores)."""
        x = np.asarray(exposure, np.float64)
        dtype = np.uint8 if self.bits == 8 else np.uint16
        out = np.empty(x.shape, dtype)
        grid = np.arange(self.table.shape[0], dtype=np.float64)
        for c in range(3):
            # Continuous code for x, rounded to the nearest stored code.
            out[..., c] = np.rint(np.interp(x[..., c], self.table[:, c], grid)).astype(dtype)
        return out

    def to_manifest(self) -> dict:
        """The manifest's ``{"type": "table"}`` form (channel 0; the format holds one curve)."""
        return {"type": "table", "values": [float(v) for v in self.table[:, 0]]}

    @classmethod
    def from_manifest(cls, value: dict) -> ResponseCurve:
        return cls(np.asarray(value["values"], np.float64))
