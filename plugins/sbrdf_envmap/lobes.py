"""The specular lobes of a BRDF model, in the two shapes environment lighting understands.

- *Cosine lobes* ``ρ_s · max(0, p·ω_i)^n`` with peak vector ``p = C·ω_r``
  (Lafortune, McAllister's SBRDF; Phong is the lobe C = (−1, −1, 1) with
  ρ_s (n + 2)/2π).  Radially symmetric about p̂, so McAllister's prefiltered
  maps and the centre-plus-ring pattern serve them exactly.
- *Beckmann lobes* with slopes ``m_x, m_y`` about the mirror direction
  (Ward, Cook–Torrance; Mühlbacher's Kurt lobe): sampled through half
  vectors (Eqs 4.5–4.9); their value is the model's own ``eval`` minus ρ_d.

Lambert has ρ_d only.  Every supported model has ``rho_d`` (sr⁻¹), which
the diffuse map D(N) serves.  Other models get a clear error, except in
the Monte Carlo reference, which needs only ``eval``.
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.errors import SbrdfError

COSINE = ("lafortune", "phong")
BECKMANN = ("ward", "cook-torrance")
DIFFUSE = ("lambert",)


def kind(model, method: str) -> str:
    """``"cosine"``, ``"beckmann"`` or ``"diffuse"``; an error naming the model when ``method`` cannot shade it."""
    name = model.name
    if method != "mc" and not any(p.name == "rho_d" for p in getattr(model, "parameters", ())):
        raise SbrdfError(f"environment method {method!r}: model {name!r} has no rho_d parameter")
    if name in COSINE or name in DIFFUSE:
        return "cosine" if name in COSINE else "diffuse"
    if name in BECKMANN:
        if method.startswith("prefiltered"):
            raise SbrdfError(f"environment method {method!r}: model {name!r} has no cosine lobes, which McAllister's "
                             "prefiltered maps need; use method: sampling or mc, or a lafortune/phong material")
        return "beckmann"
    raise SbrdfError(f"environment method {method!r} supports the models {', '.join(COSINE + BECKMANN + DIFFUSE)}; "
                     f"got {name!r} (method: mc integrates any model)")


def cosine_lobes(model, params) -> list[dict]:
    """Per lobe ``{rho_s (R,3), c (R,3), exponent (R,), beta (R,)}`` of a lafortune or phong material."""
    R = len(params["rho_d"])
    if model.name == "phong":
        n = np.asarray(params["exponent"])[:, 0]
        return [{"rho_s": np.asarray(params["rho_s"]) * ((n + 2) / (2 * np.pi))[:, None],
                 "c": np.broadcast_to([-1.0, -1.0, 1.0], (R, 3)), "exponent": n, "beta": np.zeros(R)}]
    beta = np.asarray(params["beta"])[:, 0] if model.has_beta else np.zeros(R)
    out = []
    for lobe in model.lobe_list(params):
        c = np.stack([lobe["c_x"][:, 0], lobe["c_y"][:, 0], lobe["c_z"][:, 0]], 1)
        out.append({"rho_s": np.asarray(lobe["rho_s"]), "c": c, "exponent": np.asarray(lobe["exponent"])[:, 0],
                    "beta": beta})
    return out


def peak(lobe: dict, wo: np.ndarray) -> np.ndarray:
    """Peak vector p = C'·ω_r in the surface frame, C' = R(−β) C R(β) (Eq 4.4), ``(R, 3)``."""
    cb, sb = np.cos(lobe["beta"]), np.sin(lobe["beta"])
    ox, oy = cb * wo[:, 0] + sb * wo[:, 1], -sb * wo[:, 0] + cb * wo[:, 1]
    px, py, pz = lobe["c"][:, 0] * ox, lobe["c"][:, 1] * oy, lobe["c"][:, 2] * wo[:, 2]
    return np.stack([cb * px - sb * py, sb * px + cb * py, pz], 1)


def slopes(model, params) -> tuple[np.ndarray, np.ndarray]:
    """Beckmann slopes ``(m_x, m_y)``, each ``(R,)``: Ward's α, Cook–Torrance's α."""
    if model.name == "ward" and model.anisotropic:
        return np.asarray(params["alpha_x"])[:, 0], np.asarray(params["alpha_y"])[:, 0]
    a = np.asarray(params["alpha"])[:, 0]
    return a, a


# -- GLSL: the same lobes from the GL renderer's parameter expressions ---------------------------------------------------


def glsl_cosine_lobes(model, exprs: dict) -> list[tuple[str, str, str, str]]:
    """Per lobe GLSL ``(rho_s, c, exponent, beta)`` expressions (vec3, vec3, float, float)."""
    if model.name == "phong":
        n = exprs["exponent"]
        return [(f"({exprs['rho_s']} * (({n} + 2.0) / 6.283185307))", "vec3(-1.0, -1.0, 1.0)", n, "0.0")]
    beta = exprs["beta"] if model.has_beta else "0.0"
    out = []
    for j in range(1, model.lobes + 1):
        cx = exprs[f"c_x_{j}"] if model.anisotropic else exprs[f"c_xy_{j}"]
        cy = exprs[f"c_y_{j}"] if model.anisotropic else exprs[f"c_xy_{j}"]
        out.append((exprs[f"rho_s_{j}"], f"vec3({cx}, {cy}, {exprs[f'c_z_{j}']})", exprs[f"exponent_{j}"], beta))
    return out


def glsl_slopes(model, exprs: dict) -> tuple[str, str]:
    if model.name == "ward" and model.anisotropic:
        return exprs["alpha_x"], exprs["alpha_y"]
    return exprs["alpha"], exprs["alpha"]


GLSL = """
vec3 lobe_peak(vec3 c, float beta, vec3 wo) {  // p = C' wo in the surface frame (Eq 4.4)
    float cb = cos(beta), sb = sin(beta);
    vec2 o = vec2(cb * wo.x + sb * wo.y, -sb * wo.x + cb * wo.y);
    vec3 q = c * vec3(o, wo.z);
    return vec3(cb * q.x - sb * q.y, sb * q.x + cb * q.y, q.z);
}
"""
