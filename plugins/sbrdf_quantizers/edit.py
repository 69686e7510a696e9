"""SBRDF editing and synthesis (seed 000 §4.6): compositing, diffuse replacement, synthesis from a photo.

All operate on parameter maps ``name -> (V, U, C)`` (NumPy) of one model and
return new maps; none claims physical validity (the text: "no physical
validity, but useful"), but none produces a value outside the model's bounds.
"""

from __future__ import annotations

import numpy as np


def composite(layers: list[dict], masks: list[np.ndarray]) -> dict:
    """Mask-based compositing: texel (v, u) takes the parameters of the last layer whose mask is set there.

    ``layers``: parameter maps of the same model and grid; ``masks``: ``(V, U)`` bool (or
    0..1, thresholded at 0.5), one per layer; the first layer is the background (its mask
    may be ``None``).  Parameters are *selected*, never blended: averaging nonlinear
    parameters across a soft edge would make BRDFs neither layer has (Ch 5).
    """
    if len(layers) != len(masks):
        raise ValueError(f"{len(layers)} layers but {len(masks)} masks")
    names = list(layers[0])
    shape = np.asarray(layers[0][names[0]]).shape[:2]
    choice = np.zeros(shape, np.int64)
    for k, (layer, mask) in enumerate(zip(layers, masks)):
        if set(layer) != set(names):
            raise ValueError(f"layer {k} has parameters {sorted(layer)}, layer 0 {sorted(names)}: one model only")
        if mask is None:
            continue
        m = np.asarray(mask)
        if m.shape[:2] != shape:
            raise ValueError(f"mask {k} is {m.shape[1]}×{m.shape[0]}, the layers {shape[1]}×{shape[0]}")
        choice = np.where((m > 0.5) if m.dtype != bool else m, k, choice)
    out = {}
    for n in names:
        stack = np.stack([np.asarray(layer[n], np.float64) for layer in layers])  # (L, V, U, C)
        out[n] = np.take_along_axis(stack, choice[None, ..., None], axis=0)[0]
    return out


def srgb_to_linear(image) -> np.ndarray:
    """8-bit (or [0, 1] float) sRGB -> linear [0, 1] (IEC 61966-2-1): the "gamma correction" of §4.6."""
    x = np.asarray(image)
    x = x / 255.0 if x.dtype == np.uint8 else x.astype(np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def replace_diffuse(params: dict, image: np.ndarray, linear: bool = True) -> dict:
    """Replace ρ_d with ``image`` ``(V, U, 3)`` normalised to the original ρ_d's mean, per channel.

    The blur of registration and oblique sampling is removed by a single sharp
    image taken near the normal (or a flatbed scan); its absolute level is
    meaningless, so each channel is scaled to the same average as the fitted ρ_d.
    ``linear=False`` linearises an sRGB image first.
    """
    rho_d = np.asarray(params["rho_d"], np.float64)
    img = np.asarray(image, np.float64) if linear else srgb_to_linear(image)
    if img.shape[:2] != rho_d.shape[:2]:
        raise ValueError(f"image is {img.shape[1]}×{img.shape[0]}, the SBRDF {rho_d.shape[1]}×{rho_d.shape[0]}; "
                         "resample it onto the texel grid first")
    img = img[..., :3]
    mean_img = img.mean(axis=(0, 1))
    if (mean_img <= 0).any():
        raise ValueError("replacement image has a channel with zero mean: nothing to normalise")
    return {**params, "rho_d": img * (rho_d.mean(axis=(0, 1)) / mean_img)}


def synthesize_from_photo(model, photo: np.ndarray, *, exponent_mean: float = 110.0, exponent_var: float = 1.0,
                          c_xy: float = -1.01, c_z: float = 0.9, rho_s: float = 1.0, dark_fraction: float = 0.1,
                          dark_exponent: float = 6.0, diffuse_scale: float = 1.0 / np.pi, seed: int = 0) -> dict:
    """McAllister's cherry wood (§4.6): an SBRDF from one RGB photo.

    ρ_d = the linearised photo × ``diffuse_scale`` (1/π: a pixel value read as albedo);
    ρ_s = white; n ~ Normal(``exponent_mean``, ``exponent_var``); C_x = C_y = −1.01,
    C_z = 0.9, so reflectance rises sharply at grazing (|Cω_i|^110: 9·10⁻⁶ at the normal,
    ≈ 3 at 89°) while the diffuse term dominates near the normal; the darkest
    ``dark_fraction`` of pixels (the grain, by luminance threshold) get n = ``dark_exponent``.
    ``model`` must be a 1-lobe isotropic Lafortune model.
    """
    if getattr(model, "name", "") != "lafortune" or model.lobes != 1 or model.anisotropic:
        raise ValueError("synthesize_from_photo makes a 1-lobe isotropic Lafortune SBRDF (model lafortune, lobes: 1)")
    lin = srgb_to_linear(np.asarray(photo)[..., :3])
    V, U = lin.shape[:2]
    rng = np.random.default_rng(seed)
    n = rng.normal(exponent_mean, np.sqrt(exponent_var), (V, U, 1))
    lum = lin @ np.array([0.2126, 0.7152, 0.0722])
    n[lum <= np.quantile(lum, dark_fraction)] = dark_exponent
    params = {"rho_d": lin * diffuse_scale, "rho_s_1": np.full((V, U, 3), rho_s), "c_xy_1": np.full((V, U, 1), c_xy),
              "c_z_1": np.full((V, U, 1), c_z), "exponent_1": np.clip(n, 0.1, None)}
    if model.mirror:
        params["rho_m"] = np.zeros((V, U, 3))
    return params
