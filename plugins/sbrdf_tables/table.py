"""Gonioreflectometer transfer-probability tables (seed 004 §2.3, §3.2): read, write, integrate.

Format (``docs/measured-tables.md``): CSV, ``#`` comment lines, one header row
naming the columns ``theta_i, phi_i, theta_o, phi_o`` (degrees) and one value
column, ``p`` (transfer probability density p = f_s·|cos θ_o|, sr⁻¹, what the
thesis's tables store) or ``bsdf`` (f_s, sr⁻¹).  θ_o in (90°, 180°] is the
transmission hemisphere.  An empty, ``nan`` or ``-`` value is an unmeasured
entry (occluded by the device); a measured 0 stays 0.  Incident directions may
be any sparse set (the thesis's 6 × 7 θ_i × ϕ_i grid, or 7 θ_i at ϕ_i = 0).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sbrdf_core.input_files import check_file

COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")
QUANTITIES = ("p", "bsdf")
#: |cos θ_o| below this: p / |cos θ_o| is undefined, the BSDF value is treated as unmeasured.
GRAZING_COS = 1e-6


class TableError(ValueError):
    """A malformed table; the message names the file and line."""


def direction(theta_deg, phi_deg) -> np.ndarray:
    """Unit vectors ``(..., 3)`` for θ from +z (θ > 90° is below the surface) and ϕ from +x (the tangent)."""
    t, p = np.radians(np.asarray(theta_deg, float)), np.radians(np.asarray(phi_deg, float))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


@dataclass
class MeasuredTable:
    """One single-channel BSDF table: per measured pair (ω_i, ω_o) its transfer probability.

    ``p`` is NaN where unmeasured.  Angles in degrees.
    """

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray
    p: np.ndarray
    source: str = "<memory>"

    def __post_init__(self):
        for name in COLUMNS + ("p",):
            setattr(self, name, np.asarray(getattr(self, name), dtype=np.float64).reshape(-1))

    def __len__(self):
        return self.p.size

    @property
    def wi(self) -> np.ndarray:
        return direction(self.theta_i, self.phi_i)

    @property
    def wo(self) -> np.ndarray:
        return direction(self.theta_o, self.phi_o)

    @property
    def transmission(self) -> np.ndarray:
        """Mask of entries on the transmission hemisphere (θ_o > 90°)."""
        return self.theta_o > 90.0

    @property
    def measured(self) -> np.ndarray:
        return np.isfinite(self.p)

    @property
    def abs_cos_o(self) -> np.ndarray:
        return np.abs(np.cos(np.radians(self.theta_o)))

    def bsdf(self) -> np.ndarray:
        """f_s = p / |cos θ_o| (Eq 2.4); NaN where unmeasured or at θ_o = 90° (undefined)."""
        c = self.abs_cos_o
        with np.errstate(all="ignore"):
            return np.where(c > GRAZING_COS, self.p / np.where(c > GRAZING_COS, c, 1.0), np.nan)

    def incident_directions(self) -> np.ndarray:
        """Distinct (θ_i, ϕ_i) pairs in table order, ``(N, 2)`` degrees."""
        pairs = np.stack([self.theta_i, self.phi_i], axis=1)
        _, first = np.unique(pairs, axis=0, return_index=True)
        return pairs[np.sort(first)]

    def solid_angles(self) -> np.ndarray:
        """Solid angle (sr) each entry stands for, from the outgoing grid of its incident direction.

        Per incident direction and hemisphere, the distinct θ_o and ϕ_o values
        are treated as a tensor grid; cell edges lie halfway between values,
        at the pole and at the horizon, and ϕ wraps around 360°.  A cell is
        (cos θ_lo − cos θ_hi)·Δϕ, so the cells of a full grid tile the
        hemisphere exactly (2π sr).
        """
        out = np.zeros(len(self))
        for ti, pi in self.incident_directions():
            for lower in (False, True):
                sel = (self.theta_i == ti) & (self.phi_i == pi) & (self.transmission == lower)
                if not sel.any():
                    continue
                th = np.radians(self.theta_o[sel])
                th_m = np.pi - th if lower else th  # measure from the hemisphere's own pole
                thetas = np.unique(th_m)
                edges = np.concatenate([[0.0], (thetas[1:] + thetas[:-1]) / 2, [np.pi / 2]])
                band = np.cos(edges[:-1]) - np.cos(edges[1:])
                row = np.searchsorted(thetas, th_m)
                phis = np.radians(self.phi_o[sel]) % (2 * np.pi)
                width = np.empty(sel.sum())
                for r in np.unique(row):
                    in_row = row == r
                    u = np.unique(phis[in_row])
                    if u.size == 1:
                        w = np.array([2 * np.pi])
                    else:
                        gaps = np.diff(np.concatenate([u, [u[0] + 2 * np.pi]]))
                        w = (gaps + np.roll(gaps, 1)) / 2
                    width[in_row] = w[np.searchsorted(u, phis[in_row])]
                out[np.flatnonzero(sel)] = band[row] * width
        return out

    def integrals(self) -> dict[str, np.ndarray]:
        """Per incident direction: reflectance r (Eq 2.7), transmittance t (Eq 2.8), albedo a = r + t (Eq 2.6).

        Each is Σ p dω over the measured entries of the hemisphere; unmeasured
        entries contribute nothing, so ``coverage`` (the measured fraction of
        the grid's solid angle) says how far r and t are lower bounds.
        """
        incident = self.incident_directions()
        dw = self.solid_angles()
        p = np.where(self.measured, self.p, 0.0)
        r, t, cover = (np.zeros(len(incident)) for _ in range(3))
        for k, (ti, pi) in enumerate(incident):
            sel = (self.theta_i == ti) & (self.phi_i == pi)
            r[k] = np.sum((p * dw)[sel & ~self.transmission])
            t[k] = np.sum((p * dw)[sel & self.transmission])
            total = dw[sel].sum()
            cover[k] = dw[sel & self.measured].sum() / total if total > 0 else 0.0
        return {"theta_i": incident[:, 0], "phi_i": incident[:, 1], "reflectance": r, "transmittance": t,
                "albedo": r + t, "coverage": cover}


def read_table(path) -> MeasuredTable:
    """Read a table file; :class:`TableError` names the file and line of any problem."""
    path = Path(path)
    try:
        check_file(path, text=True)  # a regular file within the text limit before the csv reader starts
    except FileNotFoundError:
        raise TableError(f"{path}: no such table file") from None
    except OSError as e:
        raise TableError(f"{path}: cannot read the table file: {e.strerror}") from None
    rows, header, header_line = [], None, 0
    with path.open(newline="") as fh:
        for line_no, row in enumerate(csv.reader(fh), start=1):
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue
            cells = [c.strip() for c in row]
            if header is None:
                header, header_line = [c.lower() for c in cells], line_no
                missing = [c for c in COLUMNS if c not in header]
                value = [c for c in header if c in QUANTITIES]
                if missing or len(value) != 1:
                    raise TableError(
                        f"{path}:{line_no}: header must name {', '.join(COLUMNS)} and one of {' or '.join(QUANTITIES)}"
                        f" (got {', '.join(cells)})")
                quantity = value[0]
                index = [header.index(c) for c in COLUMNS + (quantity,)]
                continue
            if len(cells) != len(header):
                raise TableError(f"{path}:{line_no}: {len(cells)} fields, the header (line {header_line}) has {len(header)}")
            values = []
            for name, i in zip(COLUMNS + (quantity,), index):
                text = cells[i]
                if name == quantity and text.lower() in ("", "nan", "-"):
                    values.append(np.nan)
                    continue
                try:
                    v = float(text)
                except ValueError:
                    raise TableError(f"{path}:{line_no}: {name} is not a number: {text!r}") from None
                if not np.isfinite(v):
                    raise TableError(f"{path}:{line_no}: {name} is not finite: {text!r}")
                values.append(v)
            ti, pi_, to, po, v = values
            if not 0.0 <= ti < 90.0:
                raise TableError(f"{path}:{line_no}: theta_i {ti:g} outside [0, 90): light comes from above the sample")
            if not 0.0 <= to <= 180.0:
                raise TableError(f"{path}:{line_no}: theta_o {to:g} outside [0, 180]")
            if np.isfinite(v) and v < 0:
                raise TableError(f"{path}:{line_no}: {quantity} {v:g} is negative")
            rows.append(values)
    if header is None or not rows:
        raise TableError(f"{path}: no data rows (expected a header line and one row per measured direction pair)")
    a = np.asarray(rows)
    if quantity == "bsdf":
        a[:, 4] = a[:, 4] * np.abs(np.cos(np.radians(a[:, 2])))
    return MeasuredTable(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], source=str(path))


def write_table(path, table: MeasuredTable, comment: str = "") -> Path:
    """Write ``table`` as a ``p`` CSV (unmeasured entries empty)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        fh.write("# sbrdf measured table: transfer probability p = f_s |cos theta_o| (sr^-1), angles in degrees\n")
        for line in comment.splitlines():
            fh.write(f"# {line}\n")
        w = csv.writer(fh)
        w.writerow(COLUMNS + ("p",))
        for ti, pi_, to, po, v in zip(table.theta_i, table.phi_i, table.theta_o, table.phi_o, table.p):
            w.writerow([f"{ti:g}", f"{pi_:g}", f"{to:g}", f"{po:g}", "" if not np.isfinite(v) else f"{v:.9g}"])
    return path


#: The thesis's incident grid for the anisotropic aluminium datasets (§3.1 of the notes).
THESIS_THETA_I = (0.0, 5.0, 20.0, 35.0, 50.0, 65.0)
THESIS_PHI_I = (0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0)


def grid_table(theta_i=THESIS_THETA_I, phi_i=THESIS_PHI_I, theta_step=5.0, phi_step=15.0, transmission=False,
               incident=None) -> MeasuredTable:
    """An empty (p = 0) table on the incident grid × a regular outgoing grid (θ_o at cell centres).

    ``incident`` (``(N, 2)`` degrees) overrides the θ_i × ϕ_i product.
    """
    if incident is None:
        incident = np.array([(t, p) for t in theta_i for p in phi_i], float)
    theta_o = np.arange(theta_step / 2, 90.0, theta_step)
    if transmission:
        theta_o = np.concatenate([theta_o, 180.0 - theta_o[::-1]])
    phi_o = np.arange(0.0, 360.0, phi_step)
    to, po = np.meshgrid(theta_o, phi_o, indexing="ij")
    n_out = to.size
    ti = np.repeat(incident[:, 0], n_out)
    pi_ = np.repeat(incident[:, 1], n_out)
    return MeasuredTable(ti, pi_, np.tile(to.ravel(), len(incident)), np.tile(po.ravel(), len(incident)),
                         np.zeros(len(incident) * n_out))


def table_from_model(model, params, table: MeasuredTable, noise: float = 0.0, seed: int = 0) -> MeasuredTable:
    """``table``'s directions filled with the model's p = f_s·|cos θ_o| (first channel), optional relative noise.

    Noise is multiplicative Gaussian (σ = ``noise`` of each value) plus an
    absolute floor of ``noise``·1e-3 of the table's peak, clipped at 0: what a
    sensor with a relative error and a dark-current floor would deliver.
    """
    f = model.eval(params, table.wi[None], table.wo[None])[0, :, 0]
    p = f * table.abs_cos_o
    if noise > 0:
        rng = np.random.default_rng(seed)
        p = p * (1 + noise * rng.standard_normal(p.shape)) + noise * 1e-3 * p.max() * rng.standard_normal(p.shape)
        p = np.maximum(p, 0.0)
    p = np.where(np.isfinite(table.p), p, np.nan)
    return MeasuredTable(table.theta_i, table.phi_i, table.theta_o, table.phi_o, p, table.source)
