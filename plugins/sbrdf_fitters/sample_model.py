"""SampleModel: a SampledReflectance drawn from a known BRDF model, for testing and benchmarking fitters.

A node kind with no inputs.  The material is any model plugin with
procedural parameter maps spanning each parameter's ``typical`` range (the
same maps as the ``synthetic`` capture), or one parameter set for every texel
(``params``).  Light and camera positions come from a Fibonacci spiral, from
uniform random directions, or are given explicitly (a pose plan); ω_i and ω_r
are then per texel, exactly as the Reflectance node derives them.  Gaussian
noise is absolute, in sr⁻¹ (the units the seed quotes noise levels in),
seeded per tile so any tile can be recomputed alone.  The ground-truth maps
are stored as ``truth/<parameter>`` beside the samples.

YAML::

    samples: {kind: SampleModel, params: {model: lafortune, model_params: {lobes: 2}, texels: [256, 256],
              poses: 400, noise: 0.01}}
    fit:     {kind: Fit, plugin: lm, in: {samples: samples}, params: {model: lafortune, model_params: {lobes: 2}}}
"""

from __future__ import annotations

import numpy as np

from sbrdf_core.artifacts import SampledReflectance
from sbrdf_core.geometry import fibonacci_hemisphere, tile_directions
from sbrdf_core.nodes.base import BuildContext, NodeKind, Output
from sbrdf_core.params import Param
from sbrdf_core.store import texel_tile


def sample_tile(index, maps, light_pos, camera_pos, texels, size_mm, model, noise, seed, min_cos, tile, block_info=None):
    """Kernel: one texel tile -> ``(v, u, P, 4)`` = f_r RGB + validity."""
    (v0, v1), (u0, u1) = block_info[0]["array-location"][:2]
    wi, _, wo = tile_directions(texels, size_mm, (v0, v1), (u0, u1), light_pos, camera_pos)
    params = {k: m[v0:v1, u0:u1].reshape(-1, m.shape[-1]) for k, m in maps.items()}
    f = model.eval(params, wi, wo)
    if noise > 0:
        rng = np.random.default_rng([seed, v0 // tile, u0 // tile])
        f = f + noise * rng.standard_normal(f.shape)
    valid = (wi[..., 2] > min_cos) & (wo[..., 2] > min_cos)
    out = np.concatenate([np.where(valid[..., None], f, 0.0), valid[..., None]], axis=-1)
    return out.reshape(v1 - v0, u1 - u0, -1, 4).astype(np.float32)


def material_maps(model, texels, params=None) -> dict[str, np.ndarray]:
    """Ground-truth maps ``name -> (V, U, C)``: procedural over ``typical`` ranges, or ``params`` everywhere."""
    from sbrdf_lib.patterns import pattern

    n_u, n_v = texels
    out = {}
    for k, p in enumerate(model.parameters):
        if params and p.name in params:
            value = np.broadcast_to(np.asarray(params[p.name], float).reshape(-1), (p.channels,))
            out[p.name] = np.broadcast_to(value, (n_v, n_u, p.channels)).copy()
        else:
            lo, hi = p.typical
            out[p.name] = np.stack([lo + (hi - lo) * pattern(n_u, n_v, k, c) for c in range(p.channels)], axis=-1)
    return physical(model, out, given=set(params or ()))


def physical(model, maps: dict[str, np.ndarray], given=frozenset()) -> dict[str, np.ndarray]:
    """Procedural maps scaled where they would reflect more than they receive (directional albedo > 1).

    Typical ranges drawn independently (a bright ρ_d beside a strong lobe)
    are not energy conserving; a fitter that honours the bound would then be
    judged against an impossible truth.  Parameters the graph gave are kept.
    """
    from sbrdf_core.constraints import enforce_energy

    if given & {p.name for p in model.parameters if p.magnitude}:
        return maps
    shape = next(iter(maps.values())).shape[:2]
    flat = {k: v.reshape(-1, v.shape[-1]) for k, v in maps.items()}
    fixed: dict[str, list[np.ndarray]] = {}
    step = 4096
    for s in range(0, flat[next(iter(flat))].shape[0], step):
        # coarse quadrature, so a margin below 1: the Fit node checks on a finer grid
        part, _ = enforce_energy(model, {k: v[s:s + step] for k, v in flat.items()}, 0.9, n_theta=12, n_phi=24)
        for k, v in part.items():
            fixed.setdefault(k, []).append(v)
    return {k: np.concatenate(v).reshape(shape + (-1,)) for k, v in fixed.items()}


def pose_positions(directions: str, poses: int, max_theta: float, light_mm: float, camera_mm: float, seed: int):
    """``(light_pos, camera_pos)`` ``(P, 3)`` mm from a named direction set."""
    if directions == "fibonacci":
        light = fibonacci_hemisphere(poses, max_theta)
        camera = fibonacci_hemisphere(poses, max_theta, offset=2.0)[::-1]
    else:  # uniform over the spherical cap θ ≤ max_theta
        rng = np.random.default_rng(seed)
        cap = 1 - np.cos(np.radians(max_theta))

        def draw():
            z = 1 - rng.uniform(0, cap, poses)
            phi = rng.uniform(0, 2 * np.pi, poses)
            r = np.sqrt(np.clip(1 - z * z, 0, None))
            return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)

        light, camera = draw(), draw()
    return light * light_mm, camera * camera_mm


class SampleModel(NodeKind):
    name = "SampleModel"
    doc = "Sample a known BRDF model per texel into a SampledReflectance (synthetic data for fitters)."
    output = SampledReflectance
    params = (
        Param("model", "str", "lafortune", "BRDF model the material follows", extra={"plugin_category": "brdf-model"}),
        Param("model_params", "dict", {}, "configuration of that model", extra={"params_of": "model"}),
        Param("params", "dict", {}, "parameter values used at every texel (others vary over their typical range): "
              "each a parameter of the model, a number (or one per channel) within its bounds",
              extra={"model_values_of": ("model", "model_params")}),
        Param("texels", "list", [64, 64], "texel grid [U, V]", length=2, item="int", bounds=(1, 16384)),
        Param("size_mm", "list", [100.0, 100.0], "sample size [x, y]", length=2, item="float", bounds=(1e-3, None),
              unit="mm"),
        Param("poses", "int", 400, "light/camera direction pairs", bounds=(1, 1000000)),
        Param("directions", "str", "fibonacci", "how poses are placed", choices=("fibonacci", "random")),
        Param("light_pos", "list", None, "explicit light positions [[x, y, z], ...] (a pose plan); overrides poses",
              nullable=True, unit="mm"),
        Param("camera_pos", "list", None, "explicit camera positions, one per light position", nullable=True, unit="mm"),
        Param("max_theta_deg", "float", 75.0, "largest light/view angle from the normal", bounds=(0.0, 90.0), unit="deg"),
        Param("light_distance_mm", "float", 600.0, "light distance from the sample centre", bounds=(1.0, None), unit="mm"),
        Param("camera_distance_mm", "float", 800.0, "camera distance", bounds=(1.0, None), unit="mm"),
        Param("noise", "float", 0.0, "Gaussian noise σ added to f_r", bounds=(0.0, None), unit="sr^-1"),
        Param("min_cos", "float", 0.02, "samples with cos θ_i or cos θ_r below this are invalid", bounds=(0.0, 1.0)),
        Param("seed", "int", 0, "random seed (noise per tile; random directions)"),
        Param("tile", "int", None, "texel tile edge per chunk", bounds=(1, 4096), nullable=True),
    )

    @staticmethod
    def check_params(params) -> list[tuple[str, str]]:
        """An explicit pose plan is a list of ``[x, y, z]`` mm positions, finite, one camera per light, checked
        at validation with its line rather than failing when the node runs."""
        problems: list[tuple[str, str]] = []
        counts = {}
        for key in ("light_pos", "camera_pos"):
            value = params.get(key)
            if value is None:
                continue
            for i, row in enumerate(value):
                ok = isinstance(row, list) and len(row) == 3 and all(
                    isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c) for c in row)
                if not ok:
                    problems.append((key, f"{key}[{i}] should be [x, y, z] in mm (three finite numbers), got {row!r}"))
                    break
            counts[key] = len(value)
        if not problems and "camera_pos" in counts and "light_pos" not in counts:
            problems.append(("camera_pos", "camera_pos needs light_pos: a pose plan gives both (or light_pos alone)"))
        elif not problems and len(counts) == 2 and counts["light_pos"] != counts["camera_pos"]:
            problems.append(("camera_pos", f"camera_pos has {counts['camera_pos']} positions, light_pos "
                                           f"{counts['light_pos']}: give one per pose"))
        elif not problems and counts.get("light_pos") == 0:
            problems.append(("light_pos", "light_pos is empty: give at least one pose"))
        return problems

    @classmethod
    def build(cls, ctx: BuildContext) -> Output:
        import dask.array as da

        p = ctx.params
        model = ctx.plugins().create("brdf-model", p["model"], dict(p["model_params"]))
        texels, size_mm = tuple(p["texels"]), tuple(p["size_mm"])
        if p["light_pos"] is not None:
            light = np.asarray(p["light_pos"], float).reshape(-1, 3)
            camera = np.asarray(p["camera_pos"] if p["camera_pos"] is not None else p["light_pos"], float).reshape(-1, 3)
            if camera.shape != light.shape:
                raise ValueError(f"camera_pos has {len(camera)} positions, light_pos {len(light)}: give one per pose")
        else:
            light, camera = pose_positions(p["directions"], p["poses"], p["max_theta_deg"], p["light_distance_mm"],
                                           p["camera_distance_mm"], p["seed"])
        maps = material_maps(model, texels, p["params"])
        n_u, n_v = texels
        P = len(light)
        t = texel_tile((n_v, n_u), P, channels=4, tile=p["tile"])
        index = da.zeros((n_v, n_u), chunks=(t, t), dtype=np.int8)
        packed = da.map_blocks(
            sample_tile, index, maps, light, camera, texels, size_mm, model, p["noise"], p["seed"], p["min_cos"], t,
            new_axis=[2, 3], chunks=index.chunks + ((P,), (4,)), dtype=np.float32, name=ctx.key("sample"),
        )
        arrays = {"f_r": packed[..., :3], "valid": packed[..., 3] > 0.5,
                  "light_pos": da.from_array(light), "camera_pos": da.from_array(camera)}
        arrays.update({f"truth/{k}": da.from_array(v.astype(np.float32), chunks=(t, t, v.shape[-1])) for k, v in maps.items()})
        return Output(arrays=arrays, attrs={
            "texels": list(texels), "size_mm": list(size_mm), "light": {"type": "point", "intensity": 1.0}, "tile": t,
            "truth": {"model": model.name, "model_config": dict(p["model_params"]), "parameters": model.describe()},
        })
