"""Shading-mapped materials in the cpu and gl renderers: agreement, and the BRDF chosen at render time."""

from __future__ import annotations

import numpy as np
import pytest

from sbrdf_core.errors import SbrdfError
from sbrdf_lib.scene import load_scene
from sbrdf_render import materials as mat
from sbrdf_render.cpu import render_scene
from sbrdf_shading.shade import ShadingData
from sbrdf_shading.surface import ShadingSurface

from .test_render import draw_gl, interior, relative_errors

SCENE = """
camera: {position: [0.2, -1.8, 1.4], look_at: [0, 0, 0], fov_deg: 45, resolution: [80, 60]}
materials: {m: {artifact: input}}
objects: [{shape: plane, size: [2, 2], material: m, uv_repeat: [2, 2]}]
lights: [{type: point, position: [0.6, -0.4, 1.5], intensity: 3}, {type: directional, direction: [-1, 0, 1], irradiance: 0.3}]
"""


def stack(rng, N=8, V=16, U=16, a_max=0.8):
    """A shading map whose slice t has average t·a_max/(N−1), with per-texel variation (as Eq 1 produces)."""
    gain = rng.uniform(0.6, 1.4, (1, V, U, 3))
    slices = np.linspace(0, a_max, N)[:, None, None, None] * gain
    slices /= slices.reshape(N, -1).mean(axis=1).clip(1e-12)[:, None, None, None] / np.linspace(0, a_max, N)[:, None, None, None].clip(1e-12)
    slices[0] = 0
    return ShadingData(a_max, N, slices=slices.astype(np.float32))


def material(registry, data, exponent, variant="r", above_max="clamp"):
    model = registry.create("brdf-model", "phong", {})
    base = mat.uniform("m", model, {"rho_d": 0.2, "rho_s": 0.5, "exponent": exponent})
    base.surface = ShadingSurface(data, model, model.unpack(base.maps.reshape(1, -1).astype(float)), variant, above_max)
    return base


@pytest.mark.parametrize("variant", ["r", "radiance", "texture", "angle"])
@pytest.mark.parametrize("compressed", [False, True])
def test_gl_matches_cpu_for_shading_maps(gl, registry, variant, compressed):
    rng = np.random.default_rng(4)
    data = stack(rng)
    if variant == "angle":
        data.image_average = np.linspace(0.05, 0.8, 8)
        data.theta_i_deg = np.linspace(80, 10, 8)
    if compressed:
        data = ShadingData(data.a_max, data.n_slices, k_s=rng.uniform(0.3, 1.0, (16, 16, 3)),
                           exponent=rng.uniform(0.5, 3.0, (16, 16, 3)), image_average=data.image_average,
                           theta_i_deg=data.theta_i_deg)
    scene = load_scene(SCENE)
    materials = {"m": material(registry, data, 20.0, variant, "scale")}
    ref, _ = render_scene(scene, materials)
    got, _ = draw_gl(gl, scene, materials)
    rel = relative_errors(got, ref, interior(scene, materials), floor=1e-2)
    assert ref.max() > 0 and np.sqrt(np.mean(rel**2)) < 5e-3 and np.percentile(rel, 99) < 3e-2


def test_the_brdf_is_chosen_at_render_time(registry):
    """Same data, exponent 5 vs 60: the sharper lobe makes a smaller, brighter highlight (seed 002 Fig 7)."""
    scene = load_scene(SCENE.replace("{type: directional, direction: [-1, 0, 1], irradiance: 0.3}", ""))
    data = stack(np.random.default_rng(1))
    broad, _ = render_scene(scene, {"m": material(registry, data, 5.0)})
    sharp, _ = render_scene(scene, {"m": material(registry, data, 60.0)})
    lum = [img.mean(-1) for img in (broad, sharp)]
    assert lum[1].max() > lum[0].max()
    assert (lum[1] > 0.5 * lum[1].max()).sum() < (lum[0] > 0.5 * lum[0].max()).sum()


#: a_max of the shading map graphs/shading-map.yaml computes from its light-arc capture (``sbrdf info
#: runs/shading-map/shading``), which scenes/shading-map.yaml is tuned for.
SHIPPED_A_MAX = 0.186


def shipped_scene_render(registry, exponent, text=None):
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    text = text if text is not None else (root / "scenes" / "shading-map.yaml").read_text()
    scene = load_scene(text.replace("resolution: [480, 360]", "resolution: [160, 120]"))
    ref = scene.materials["suede"]
    shading = dict(ref.surface["options"])
    model = registry.create("brdf-model", ref.model, dict(ref.model_params))
    base = mat.uniform("suede", model, {**ref.params, "exponent": exponent})
    data = stack(np.random.default_rng(4), a_max=SHIPPED_A_MAX)
    base.surface = ShadingSurface(data, model, model.unpack(base.maps.reshape(1, -1).astype(float)),
                                  shading["variant"], shading["above_max"], shading["sigma"])
    return render_scene(scene, {"suede": base})[0]


def test_the_shipped_shading_map_scene_shows_the_exponent(registry):
    """Issue 23: with ρ_d = 0.25, ρ_s = 0.6 and above_max: clamp every lit pixel of scenes/shading-map.yaml
    looked up above a_max, so exponent 5 and 200 rendered the same image.  The shipped parameters must let the
    exponent change the picture: a mean change of more than 10 % of the image's mean, over a fifth of the pixels."""
    broad, sharp = (shipped_scene_render(registry, n) for n in (5.0, 200.0))
    covered = (broad.sum(-1) > 0) | (sharp.sum(-1) > 0)
    diff = np.abs(broad - sharp).mean(-1)[covered]
    scale = broad.mean(-1)[covered].mean()
    assert diff.mean() > 0.1 * scale
    assert np.mean(diff > 0.05 * scale) > 0.2


def test_a_shading_map_input_needs_a_shading_material(registry):
    from sbrdf_core.types import InputArtifact

    class Art:
        kind, url = "ShadingMap", "/nowhere"

    scene = load_scene(SCENE)
    with pytest.raises(SbrdfError, match="shading_map: input"):
        mat.resolve(scene, InputArtifact(Art()), registry)


@pytest.mark.slow  # a GL render and the CPU reference of the same scene under an environment map
def test_shading_maps_under_environment_lighting(gl, registry):
    """Eq 3: the environment as directional lights, each through the shading map; cpu and gl agree, and a brighter
    sky gives proportionally more light (the map's lookups are below a_max here)."""
    from pathlib import Path

    sky = Path(__file__).resolve().parents[2] / "scenes" / "envmap_sky.exr"
    text = SCENE.replace("lights: [", f"environment: {{file: {sky}, intensity: INTENSITY}}\nlights: [") \
        .replace("{type: point, position: [0.6, -0.4, 1.5], intensity: 3}, ", "")
    data = stack(np.random.default_rng(2))
    images = {}
    for intensity in (0.05, 0.1):
        scene = load_scene(text.replace("INTENSITY", str(intensity)))
        materials = {"m": material(registry, data, 10.0)}
        ref, _ = render_scene(scene, materials, registry=registry)
        got, _ = draw_gl(gl, scene, materials)
        rel = relative_errors(got, ref, interior(scene, materials), floor=1e-2)
        assert ref.max() > 0 and np.sqrt(np.mean(rel**2)) < 5e-3
        images[intensity] = ref
    assert images[0.1].sum() > images[0.05].sum() * 1.2  # the sky adds light on top of the directional light
