"""GLSL for shading-map rendering: the same lookups as :mod:`sbrdf_shading.shade`, for the GL renderer.

:func:`shading_glsl` returns a self-contained snippet (no ``#version``) that
declares its uniforms, includes the BRDF model's ``brdf_<name>`` function and
defines

.. code-block:: glsl

    vec3 shading_lookup(vec2 uv, vec3 value);                 // the operator S, per channel
    vec3 shade(vec2 uv, vec3 wi, vec3 wo, vec3 irradiance);   // radiance, local frame (+z normal)
    vec3 shade_environment(vec2 uv, vec3 wo);                 // Eq 3, with environment_samples > 0

Uniforms (set every one; :func:`uniform_values` computes them):

=========================  ===========  ===================================================================
name                       type         meaning
=========================  ===========  ===================================================================
``u_shading_map``          sampler3D    full stack: RGB float texture of size (U, V, N), slices along r;
                                        LINEAR filtering, s/t REPEAT, r CLAMP_TO_EDGE (compressed=False)
``u_k_s_map``              sampler2D    compressed: k_s map (U, V), LINEAR, REPEAT (compressed=True)
``u_exponent_map``         sampler2D    compressed: exponent K map (U, V), LINEAR, REPEAT (compressed=True)
``u_a_max``                float        largest acquired average, sr⁻¹
``u_slices``               float        N
``u_sigma``                float        σ of Eq 2
``u_texture_average``      float        variant ``texture``: average of the slice used as texture
``u_angle_table[91]``      float[91]    variant ``angle``: a(θ) at θ = 0..90° (``shade.angle_table``)
``u_brdf_<parameter>``     vec3/float   the BRDF model's (global) parameters, in the model's declared names
``u_env_dir[D]``           vec3[D]      with ``environment_samples=D``: directions of the environment's samples
``u_env_radiance[D]``      vec3[D]      with ``environment_samples=D``: L_i dω of each sample (Eq 3)
=========================  ===========  ===================================================================

Only the uniforms the chosen variant needs are declared.  Models follow the
convention ``vec3 brdf_<name>(vec3 wi, vec3 wo, <parameters in declared
order>)`` (or override ``glsl_call``, as the multi-lobe ``lafortune`` does).
"""

from __future__ import annotations

import numpy as np

from .shade import ABOVE_MAX, ANGLE_TABLE_SIZE, VARIANTS, ShadingData, angle_table


def _model_call(model) -> tuple[str, str]:
    """Uniform declarations of the model's parameters and the call through ``BRDFModel.glsl_call``."""
    decl = "\n".join(f"uniform {'vec3' if p.channels == 3 else 'float'} u_brdf_{p.name};" for p in model.parameters)
    return decl, model.glsl_call("wi", "wo", {p.name: f"u_brdf_{p.name}" for p in model.parameters})


def shading_glsl(model, *, variant: str = "r", above_max: str = "clamp", compressed: bool = False,
                 environment_samples: int = 0) -> str:
    """GLSL source of ``shading_lookup`` and ``shade`` for ``model``; see the module docstring for uniforms.

    With ``environment_samples`` = D > 0 it also defines ``vec3 shade_environment(vec2 uv, vec3 wo)``
    (Eq 3) over the uniform arrays ``u_env_dir[D]`` and ``u_env_radiance[D]`` (L_i dω), which
    :func:`sbrdf_shading.shade.environment_samples` computes.
    """
    if variant not in VARIANTS:
        raise ValueError(f"variant is {variant!r}; expected one of {list(VARIANTS)}")
    if above_max not in ABOVE_MAX:
        raise ValueError(f"above_max is {above_max!r}; expected one of {list(ABOVE_MAX)}")
    decl, call = _model_call(model)
    head = ["uniform float u_a_max;", "uniform float u_slices;", "uniform float u_sigma;"]
    if compressed:
        head += ["uniform sampler2D u_k_s_map;", "uniform sampler2D u_exponent_map;"]
        fetch = (
            "    vec3 k = texture(u_k_s_map, uv).rgb;\n"
            "    vec3 K = texture(u_exponent_map, uv).rgb;\n"
            "    vec3 s;\n"
            "    for (int c = 0; c < 3; ++c) s[c] = xc[c] > 0.0 ? k[c] * exp(K[c] * log(xc[c])) : 0.0;\n"
        )
    else:
        head += ["uniform sampler3D u_shading_map;"]
        # Layer centre (l + 0.5) / N: hardware linear filtering between layers = linear in r.
        fetch = (
            "    vec3 layer = (xc * (u_slices - 1.0) + 0.5) / u_slices;\n"
            "    vec3 s;\n"
            "    for (int c = 0; c < 3; ++c) s[c] = texture(u_shading_map, vec3(uv, layer[c]))[c];\n"
        )
    scale = "    s *= max(x, vec3(1.0));\n" if above_max == "scale" else ""
    if variant == "texture":
        head.append("uniform float u_texture_average;")
    if variant == "angle":
        head.append(f"uniform float u_angle_table[{ANGLE_TABLE_SIZE}];")
    lookup = (
        "vec3 shading_lookup(vec2 uv, vec3 value) {\n"
        "    vec3 x = max(value, vec3(0.0)) / u_a_max;\n"
        "    vec3 xc = min(x, vec3(1.0));\n"
        f"{fetch}{scale}"
        "    return s;\n"
        "}\n"
    )
    body = {
        "r": "    return shading_lookup(uv, r) * irradiance;\n",
        "radiance": "    return shading_lookup(uv, r * irradiance);\n",
        "texture": ("    vec3 tex = shading_lookup(uv, vec3(u_texture_average)) / u_texture_average;\n"
                    "    return tex * r * irradiance;\n"),
        "angle": ("    float theta = degrees(acos(clamp(wi.z, 0.0, 1.0)));\n"
                  f"    int i0 = min(int(floor(theta)), {ANGLE_TABLE_SIZE - 2});\n"
                  "    float t = theta - float(i0);\n"
                  "    float a = mix(u_angle_table[i0], u_angle_table[i0 + 1], t);\n"
                  "    a = max(a, u_a_max / (u_slices - 1.0));\n"
                  "    vec3 tex = shading_lookup(uv, vec3(a)) / a;\n"
                  "    return tex * r * irradiance;\n"),
    }[variant]
    shade = (
        "vec3 shade(vec2 uv, vec3 wi, vec3 wo, vec3 irradiance) {\n"
        "    if (wi.z <= 0.0 || wo.z <= 0.0) return vec3(0.0);\n"
        f"    vec3 r = u_sigma * {call} * wi.z;\n"
        f"{body}"
        "}\n"
    )
    env = ""
    if environment_samples:
        D = int(environment_samples)
        head += [f"uniform vec3 u_env_dir[{D}];", f"uniform vec3 u_env_radiance[{D}];"]
        if variant == "radiance":  # the lookup outside the integral
            env = (
                "vec3 shade_environment(vec2 uv, vec3 wo) {\n"
                "    vec3 acc = vec3(0.0);\n"
                f"    for (int j = 0; j < {D}; ++j) {{\n"
                "        vec3 wi = u_env_dir[j];\n"
                "        if (wi.z <= 0.0 || wo.z <= 0.0) continue;\n"
                f"        acc += u_sigma * {call} * wi.z * u_env_radiance[j];\n"
                "    }\n"
                "    return shading_lookup(uv, acc);\n"
                "}\n")
        else:
            env = (
                "vec3 shade_environment(vec2 uv, vec3 wo) {\n"
                "    vec3 acc = vec3(0.0);\n"
                f"    for (int j = 0; j < {D}; ++j) acc += shade(uv, u_env_dir[j], wo, u_env_radiance[j]);\n"
                "    return acc;\n"
                "}\n")
    return "\n".join(head) + "\n" + decl + "\n" + model.glsl() + "\n" + lookup + "\n" + shade + "\n" + env


def uniform_values(data: ShadingData, model, params, *, variant: str = "r", sigma: float = 1.0,
                   texture_slice: int = -1, environment=None, environment_resolution=(8, 16)) -> dict[str, object]:
    """Values of the scalar/array uniforms for :func:`shading_glsl` (textures are bound by the caller).

    Texture data for the samplers: ``data.slices`` as a ``(N, V, U, 3)`` float32 array is a 3D texture of
    size (U, V, N) in moderngl's ``ctx.texture3d((U, V, N), 3, slices.tobytes(), dtype="f4")``;
    ``data.k_s``/``data.exponent`` ``(V, U, 3)`` are 2D textures of size (U, V).
    """
    out: dict[str, object] = {"u_a_max": float(data.a_max), "u_slices": float(data.n_slices), "u_sigma": float(sigma)}
    if variant == "texture":
        out["u_texture_average"] = float(data.a_max * (texture_slice % data.n_slices) / (data.n_slices - 1))
    if variant == "angle":
        out["u_angle_table"] = [float(v) for v in angle_table(data)]
    if environment is not None:
        from .shade import environment_samples

        dirs, radiance = environment_samples(environment, environment_resolution)
        out["u_env_dir"] = [tuple(map(float, d)) for d in dirs]
        out["u_env_radiance"] = [tuple(map(float, r)) for r in radiance]
    for p in model.parameters:
        v = np.broadcast_to(np.asarray(params[p.name], np.float64).reshape(-1), (p.channels,))
        out[f"u_brdf_{p.name}"] = tuple(float(x) for x in v) if p.channels == 3 else float(v[0])
    return out
