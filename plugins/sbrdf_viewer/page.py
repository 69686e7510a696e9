"""The viewer page: one self-contained HTML file (WebGL2, inlined script, embedded data) of a fitted or quantized SBRDF.

What is embedded (base64 little-endian float32, no external file, no network):

- the model's parameter maps packed as in the ``gl`` renderer (:func:`sbrdf_lib.gl.parameter_exprs`: parameters in
  ``model.parameters`` order, four channels per RGBA32F texture), uploaded with ``NEAREST`` filtering and repeat
  wrapping; a TextureSet is decoded through its own quantizer (:func:`sbrdf_core.nodes.render.open_material`);
  maps larger than ``max_size`` texels per side are subsampled (every k-th texel, stated in the page);
- the error maps of the fit (``rms``, ``rms_holdout``, ``samples``) and, for a TextureSet, the quantization ``error``,
  in one more RGBA32F texture (NaN where absent, drawn grey in false colour);
- the samples of a ``sample_grid`` × ``sample_grid`` grid of texels (evenly spaced texel centres) from the
  SampledReflectance the fit came from (its provenance ``inputs.samples.url``): per valid sample the half-vector
  angle θ_h, the measured luminance of f_r and the fitted model's luminance at the same directions (``model.eval``),
  at most ``max_samples`` per texel (evenly strided).  A click on a texel plots the nearest embedded texel's samples.

The fragment shader is the model's own GLSL (``model.glsl()`` and ``model.glsl_call``) under a ``#version 300 es``
header with ``highp`` precision, lit as the ``gl`` renderer lights a point light (E = I / r², f_r · E · cos θ, the
same tangent frame), so a page rendered at a given eye and light matches the ``gl`` renderer's image of the same
scene (``scene_for``).
"""

from __future__ import annotations

import base64
import html
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from sbrdf_core import contracts
from sbrdf_core.artifacts import ParamMaps, SampledReflectance, TextureSet
from sbrdf_core.errors import SbrdfError
from sbrdf_core.geometry import directions_to, texel_centres
from sbrdf_core.nodes.render import open_material
from sbrdf_core.store import Artifact, open_artifact
from sbrdf_lib.gl import parameter_exprs

__all__ = ["DEFAULT_VIEW", "LUMA", "collect", "fragment_source", "page_html", "scene_for", "write_page"]

LUMA = np.array([0.2126, 0.7152, 0.0722])  # linear Rec. 709 luminance, as sbrdf_viewer.plot

#: The page's starting view (plane units: the plane is 2 wide).  Also what ``scene_for`` writes by default.
DEFAULT_VIEW = {"eye": [0.0, -2.4, 1.7], "light": [0.8, 0.6, 2.0], "intensity": 6.0, "exposure": 1.0,
                "width": 640, "height": 480, "fov_deg": 40.0}


def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a, "<f4").tobytes()).decode("ascii")


def _provenance_input(art, name: str) -> str | None:
    return ((art.attrs.get("provenance") or {}).get("inputs") or {}).get(name, {}).get("url")


def fragment_source(model) -> str:
    """The page's fragment shader (GLSL ES 3.00): the model's GLSL, one point light, false colour of any channel."""
    ntex, exprs = parameter_exprs(model, "p")
    nch = sum(p.channels for p in model.parameters)
    two_sided = bool(contracts.optional(model, "two_sided", "brdf-model"))
    aniso = bool(contracts.optional(model, "anisotropic", "brdf-model"))
    out = ["#version 300 es", "precision highp float;", "precision highp int;", "precision highp sampler2D;",
           "in vec3 v_pos;", "in vec3 v_normal;", "in vec4 v_tangent;", "in vec2 v_uv;", "out vec4 frag;",
           "uniform vec3 u_eye;", "uniform vec3 u_light_pos;", "uniform vec3 u_light_power;",
           "uniform float u_exposure;", "uniform int u_mode;", "uniform int u_channel;", "uniform vec2 u_range;",
           "uniform sampler2D u_extra;"]
    out += [f"uniform sampler2D u_params_{k};" for k in range(ntex)]
    out.append(model.glsl())
    out.append(VIRIDIS)
    sel = [f"    if (k == {c}) return p_{c // 4}.{'xyzw'[c % 4]};" for c in range(nch)]
    sel += [f"    if (k == {nch + j}) return e.{'xyzw'[j]};" for j in range(4)]
    out.append("float channel_value(int k, " + ", ".join(f"vec4 p_{k}" for k in range(ntex)) + ", vec4 e) {\n"
               + "\n".join(sel) + "\n    return 0.0;\n}")
    call = model.glsl_call("wi", "wo", exprs)
    lit = "c != 0.0" if two_sided else "c > 0.0"
    frame = (["    vec3 T = normalize(v_tangent.xyz - N * dot(N, v_tangent.xyz));",
              "    vec3 B = (v_tangent.w < 0.0 ? -1.0 : 1.0) * cross(N, T);"] if aniso else
             ["    vec3 T = normalize(cross(abs(N.z) < 0.9 ? vec3(0.0, 0.0, 1.0) : vec3(1.0, 0.0, 0.0), N));",
              "    vec3 B = cross(N, T);"])
    body = ["void main() {"]
    body += [f"    vec4 p_{k} = texture(u_params_{k}, v_uv);" for k in range(ntex)]
    body += ["    vec4 e = texture(u_extra, v_uv);",
             "    if (u_mode == 1) {",
             "        float x = channel_value(u_channel, " + ", ".join(f"p_{k}" for k in range(ntex)) + ", e);",
             "        if (isnan(x) || isinf(x)) { frag = vec4(0.5, 0.5, 0.5, 1.0); return; }",
             "        float t = clamp((x - u_range.x) / max(u_range.y - u_range.x, 1e-30), 0.0, 1.0);",
             "        frag = vec4(viridis(t), 1.0);",
             "        return;",
             "    }",
             "    vec3 N = normalize(v_normal);"] + frame
    body += ["    vec3 V = normalize(u_eye - v_pos);",
             "    vec3 wo = vec3(dot(T, V), dot(B, V), dot(N, V));",
             "    vec3 L = vec3(0.0);",
             "    vec3 d = u_light_pos - v_pos;",
             "    float r2 = dot(d, d);",
             "    vec3 Lw = d * inversesqrt(r2);",
             "    vec3 E = u_light_power / r2;",
             "    float c = dot(N, Lw);",
             f"    if ({lit}) {{",
             "        vec3 wi = vec3(dot(T, Lw), dot(B, Lw), c);",
             f"        L += {call} * E * {'abs(c)' if two_sided else 'c'};",
             "    }",
             "    vec3 x = clamp(L * u_exposure, 0.0, 1.0);",
             "    if (any(isnan(x))) x = vec3(0.0);",
             "    vec3 s = mix(1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, 12.92 * x, vec3(lessThanEqual(x, vec3(0.0031308))));",
             "    frag = vec4(s, 1.0);",
             "}"]
    return "\n".join(out + body) + "\n"


VERTEX = """#version 300 es
precision highp float;
uniform mat4 u_mvp;
in vec3 in_pos;
in vec3 in_normal;
in vec4 in_tangent;
in vec2 in_uv;
out vec3 v_pos;
out vec3 v_normal;
out vec4 v_tangent;
out vec2 v_uv;
void main() {
    v_pos = in_pos;
    v_normal = in_normal;
    v_tangent = in_tangent;
    v_uv = in_uv;
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}
"""

# A polynomial fit of matplotlib's viridis (public domain, Matt Zucker's fit).
VIRIDIS = """vec3 viridis(float t) {
    const vec3 c0 = vec3(0.2777273272234177, 0.005407344544966578, 0.3340998053353061);
    const vec3 c1 = vec3(0.1050930431085774, 1.404613529898575, 1.384590162594685);
    const vec3 c2 = vec3(-0.3308618287255563, 0.214847559468213, 0.09509516302823659);
    const vec3 c3 = vec3(-4.634230498983486, -5.799100973351585, -19.33244095627987);
    const vec3 c4 = vec3(6.228269936347081, 14.17993336680509, 56.69055260068105);
    const vec3 c5 = vec3(4.776384997670288, -13.74514537774601, -65.35303263337234);
    const vec3 c6 = vec3(-5.435455855934631, 4.645852612178535, 26.3124352495832);
    return clamp(c0 + t * (c1 + t * (c2 + t * (c3 + t * (c4 + t * (c5 + t * c6))))), 0.0, 1.0);
}"""


def _channel_names(model) -> list[str]:
    names = []
    for p in model.parameters:
        names += [p.name] if p.channels == 1 else [f"{p.name}.{'rgba'[c] if p.channels <= 4 else c}" for c in range(p.channels)]
    return names


def _range(a: np.ndarray) -> list[float]:
    f = a[np.isfinite(a)]
    if not f.size:
        return [0.0, 1.0]
    lo, hi = (float(x) for x in np.percentile(f, [1, 99]))
    return [lo, hi if hi > lo else lo + 1e-6]


def collect(registry, url: str, *, sample_grid: int = 16, max_samples: int = 400, max_size: int = 512,
            samples_url: str | None = None) -> dict[str, Any]:
    """Everything the page embeds, from the ParamMaps or TextureSet artifact at ``url`` (see the module docstring)."""
    art = open_artifact(url, (ParamMaps, TextureSet))
    material = open_material(registry, url)
    model = material.model
    U, V = material.texels
    step = max(1, -(-max(U, V) // max_size))
    maps = np.concatenate([np.asarray(material.params[p.name], np.float32).reshape(V, U, -1)
                           for p in model.parameters], axis=-1)
    K = maps.shape[-1]
    fit_art: Artifact | None = art  # the ParamMaps with the fit's statistics, if the page can find it
    if art.kind == TextureSet.kind:
        fit_url = _provenance_input(art, "params")
        try:
            fit_art = open_artifact(fit_url, ParamMaps) if fit_url else None
        except Exception:  # moved or removed: the page shows what it has
            fit_art = None
    extra = np.full((V, U, 4), np.nan, np.float32)
    extra_names = ["rms", "rms_holdout", "samples", "quantization_error"]
    if fit_art is not None:
        for j, n in enumerate(extra_names[:3]):
            if n in fit_art.names():
                extra[..., j] = fit_art.read(n)
    if art.kind == TextureSet.kind and "error" in art.names():
        extra[..., 3] = art.read("error")
    maps, extra = maps[::step, ::step], extra[::step, ::step]
    Vs, Us = maps.shape[:2]
    ntex = (K + 3) // 4
    packed = np.zeros((Vs, Us, ntex * 4), np.float32)
    packed[..., :K] = maps
    channels: list[dict[str, Any]] = [{"name": n, "range": _range(packed[..., k])}
                                      for k, n in enumerate(_channel_names(model))]
    channels += [{"name": n, "range": _range(extra[..., j])} for j, n in enumerate(extra_names)
                 if np.isfinite(extra[..., j]).any()]
    index = {n: k for k, n in enumerate(_channel_names(model) + extra_names)}
    for ch in channels:
        ch["index"] = index[ch["name"]]
    data = {
        "model": model.name, "model_config": dict(art.attrs.get("model_config", {})), "kind": art.kind,
        "source": str(url), "texels": [U, V], "size_mm": list(material.size_mm), "stride": step,
        "shape": [Vs, Us], "ntex": ntex, "params": [_b64(packed[..., 4 * k:4 * k + 4]) for k in range(ntex)],
        "extra": _b64(extra), "channels": channels,
        "anisotropic": bool(contracts.optional(model, "anisotropic", "brdf-model")),
        "samples": None, "view": dict(DEFAULT_VIEW), "model_textures": [],
    }
    # Material-wide textures the model's own GLSL samples (a tabulated model's table), as the gl renderer uploads them.
    for uniform, array in ((contracts.optional(model, "gl_textures", "brdf-model") or dict)() or {}).items():
        a = np.asarray(array, np.float32)
        a = a.reshape(a.shape[0], a.shape[1], -1)
        data["model_textures"].append({"uniform": uniform, "shape": list(a.shape), "data": _b64(a)})
    data["view"]["exposure"] = _auto_exposure(model, packed[..., :K], DEFAULT_VIEW)
    if art.kind == TextureSet.kind:
        data["quantizer"] = art.attrs.get("quantizer")
    samples_url = samples_url or _provenance_input(art, "samples") or (
        _provenance_input(fit_art, "samples") if fit_art is not None else None)
    if samples_url and sample_grid > 0:
        try:
            s_art = open_artifact(samples_url, SampledReflectance)
        except Exception as e:  # noqa: BLE001 - the page still shows the maps
            data["samples_note"] = f"samples not embedded: {samples_url} cannot be opened ({e})"
        else:
            data["samples"] = _samples(model, material, s_art, sample_grid, max_samples)
    return data


def _auto_exposure(model, maps: np.ndarray, view: dict) -> float:
    """The starting exposure: 0.8 / the 99th percentile of the radiance a few typical light and view directions give.

    Directions: light at 45° from the normal, view at 0°, 20°, 45° (the mirror direction) and 60° on the other
    side (back-scatter), over at most 64×64 of the texels; irradiance of the page's default light at its distance.
    """
    V, U, _ = maps.shape
    sv, su = max(1, V // 64), max(1, U // 64)
    sub = maps[::sv, ::su].reshape(-1, maps.shape[-1]).astype(np.float64)
    params, k = {}, 0
    for p in model.parameters:
        params[p.name] = sub[:, k:k + p.channels]
        k += p.channels
    T = len(sub)
    s45 = np.sin(np.radians(45.0))
    wi = np.broadcast_to(np.array([s45, 0.0, s45]), (T, 4, 3))
    th = np.radians([0.0, 20.0, 45.0, -60.0])
    wo = np.broadcast_to(np.stack([-np.sin(th), np.zeros(4), np.cos(th)], 1), (T, 4, 3))
    try:
        f = np.asarray(model.eval(params, np.ascontiguousarray(wi), np.ascontiguousarray(wo)), np.float64) @ LUMA
    except Exception:  # noqa: BLE001 - a model that cannot be evaluated here still gets a page
        return 1.0
    E = view["intensity"] / float(np.dot(view["light"], view["light"])) * s45
    f = f[np.isfinite(f) & (f > 0)] * E
    return float(0.8 / np.percentile(f, 99)) if f.size else 1.0


def _samples(model, material, s_art, grid: int, max_samples: int) -> dict:
    """Per texel of an evenly spaced grid: θ_h (deg), measured and fitted luminance of every (strided) valid sample."""
    U, V = material.texels
    gu, gv = min(grid, U), min(grid, V)
    us = ((np.arange(gu) + 0.5) * U / gu).astype(int)
    vs = ((np.arange(gv) + 0.5) * V / gv).astype(int)
    f_r = np.asarray(s_art.array("f_r")[vs][:, us], np.float64)  # (gv, gu, P, 3)
    valid = np.asarray(s_art.array("valid")[vs][:, us])
    light, camera = s_art.read("light_pos"), s_art.read("camera_pos")
    pts = texel_centres(tuple(s_art.attrs.get("texels", (U, V))), tuple(s_art.attrs.get("size_mm", material.size_mm)))
    pts = pts[vs][:, us].reshape(-1, 3)
    wi, _ = directions_to(pts, np.asarray(light, float).reshape(-1, 3))
    wo, _ = directions_to(pts, np.asarray(camera, float).reshape(-1, 3))
    T = len(pts)
    params = {p.name: np.asarray(material.params[p.name][vs][:, us], np.float64).reshape(T, -1)
              for p in model.parameters}
    fit = model.eval(params, wi, wo)  # (T, P, 3)
    h = wi + wo
    theta_h = np.degrees(np.arccos(np.clip(h[..., 2] / np.maximum(np.linalg.norm(h, axis=-1), 1e-12), -1, 1)))
    meas_l = f_r.reshape(T, -1, 3) @ LUMA
    fit_l = fit @ LUMA
    ok = valid.reshape(T, -1) & np.isfinite(meas_l) & np.isfinite(fit_l)
    offsets, th, me, fi = [0], [], [], []
    for t in range(T):
        idx = np.flatnonzero(ok[t])
        if len(idx) > max_samples:
            idx = idx[np.linspace(0, len(idx) - 1, max_samples).astype(int)]
        th.append(theta_h[t, idx])
        me.append(meas_l[t, idx])
        fi.append(fit_l[t, idx])
        offsets.append(offsets[-1] + len(idx))
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)  # noqa: E731
    return {"url": s_art.url, "grid": [gu, gv], "us": us.tolist(), "vs": vs.tolist(), "offsets": offsets,
            "theta_h": _b64(cat(th)), "measured": _b64(cat(me)), "fitted": _b64(cat(fi)),
            "max_per_texel": max_samples, "total": offsets[-1]}


def page_html(data: dict, model) -> str:
    """The HTML of the page: ``data`` (from :func:`collect`) and the shaders inlined."""
    from .template import TEMPLATE

    payload = json.dumps({**data, "vertex": VERTEX, "fragment": fragment_source(model)}, separators=(",", ":"))
    payload = payload.replace("</", "<\\/")  # never close the script element early
    return (TEMPLATE.replace("%%TITLE%%", html.escape(f"sbrdf view: {data['source']}"))
            .replace("%%DATA%%", payload))


def write_page(registry, url: str, out: str | Path, **kw) -> tuple[Path, dict]:
    """Write ``out/index.html`` for the artifact at ``url``; the path and ``{bytes, write_s, data}``."""
    t0 = time.perf_counter()
    data = collect(registry, url, **kw)
    model = registry.create("brdf-model", data["model"], data["model_config"])
    text = page_html(data, model)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "index.html"
    path.write_text(text, encoding="utf-8")
    return path, {"bytes": path.stat().st_size, "write_s": time.perf_counter() - t0, "data": data}


def scene_for(material: str, eye, light, intensity: float, width: int, height: int, aspect: float = 1.0,
              fov_deg: float = 40.0, obj: str = "plane") -> str:
    """A scene file (YAML text) for the ``gl``/``cpu`` renderers showing what the page shows at that view.

    ``material`` is the artifact's path as the scene file should name it; ``aspect`` = size_mm[1] / size_mm[0].
    No antialiasing and ``nearest`` lookups, as the page draws.
    """
    shape = (f"{{shape: plane, size: [2.0, {2.0 * aspect!r}]}}" if obj == "plane" else "{shape: sphere, radius: 1.0}")
    f = lambda v: "[" + ", ".join(repr(float(x)) for x in v) + "]"  # noqa: E731
    return (f"camera: {{position: {f(eye)}, look_at: [0.0, 0.0, 0.0], fov_deg: {float(fov_deg)!r}, "
            f"resolution: [{int(width)}, {int(height)}]}}\n"
            f"materials:\n  sample: {{artifact: {json.dumps(material)}, filter: nearest}}\n"
            f"objects:\n  - {shape}\n"
            f"lights:\n  - {{type: point, position: {f(light)}, intensity: {float(intensity)!r}}}\n"
            "antialias: 1\n")


def check_url(url: str) -> None:
    """A helpful error for a path that is not a material."""
    if not Path(url).exists() and "://" not in url:
        raise SbrdfError(f"sbrdf view: {url} does not exist (give RUN/NODE, e.g. runs/sbrdf-render/fit)")
