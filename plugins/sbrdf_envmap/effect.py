"""The ``environment`` scene effect: image-based lighting for spatially varying BRDFs in ``cpu`` and ``gl``.

Consulted only when a scene has ``environment:``; its options come from
``environment: {options: {...}}`` (declared in :data:`sbrdf_envmap.PARAMS`).
Methods (``docs/environment-lighting.md``):

- ``prefiltered-discrete`` / ``prefiltered-mip``: McAllister's Eq 6.18 with
  the maps of :mod:`sbrdf_envmap.prefilter` (cosine-lobe models);
- ``sampling``: Mühlbacher's deterministic filtered in-lobe sampling
  (:mod:`sbrdf_envmap.sampling`), diffuse from D(N);
- ``mc``: the Monte Carlo reference (any model; cpu only in one pass,
  ``progressive`` in gl: ``mc_samples`` per frame, averaged over frames).

The maps are built once per (file, options) and cached in the process.
"""

from __future__ import annotations

import logging
import os
import threading
from typing import TYPE_CHECKING

import numpy as np

from sbrdf_core.errors import SbrdfError

from . import ENVIRONMENT_OPTIONS, cubemap, lobes, prefilter, sampling

if TYPE_CHECKING:
    from .glsl import GLResources

logger = logging.getLogger(__name__)

METHODS = ("prefiltered-discrete", "prefiltered-mip", "sampling", "mc", "progressive")
_CACHE: dict = {}
_LOCK = threading.Lock()


def _frame_from_normal(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangent frame the GL shader builds for isotropic materials (any frame around N)."""
    ref = np.where((np.abs(n[:, 2]) < 0.9)[:, None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    t = np.cross(ref, n)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t)


def mc_lobes(model, params, wo) -> dict:
    """The lobe samplers the Monte Carlo reference uses for a model (none for models it does not know)."""
    try:
        kind = lobes.kind(model, "mc")
    except SbrdfError:
        return {}
    if kind == "cosine":
        out = []
        for lobe in lobes.cosine_lobes(model, params):
            p = lobes.peak(lobe, wo)
            pn = np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-300)
            out.append((p / pn, np.asarray(lobe["exponent"], np.float64)))
        return {"cosine": out}
    if kind == "beckmann":
        return {"beckmann": [lobes.slopes(model, params)]}
    return {}


class EnvironmentEffect:
    """Environment lighting; see the module docstring and the ``sbrdf_scene_effects`` hook for the protocol."""

    name = "environment"

    params = ENVIRONMENT_OPTIONS

    def __init__(self, *, method: str = "prefiltered-discrete", size: int = 32, prefiltered_size: int = 32,
                 diffuse_size: int = 16, cosine: str = "normalized", prefilter: str = "auto", samples: int = 7,
                 estimator: str = "4.25", xi_border: float = sampling.XI_BORDER, ring_radius: float = sampling.RING_RADIUS,
                 line_threshold: float = 4.0, mc_samples: int = 64, seed: int = 0):
        for nm, v in (("size", size), ("prefiltered_size", prefiltered_size), ("diffuse_size", diffuse_size)):
            if v & (v - 1):
                raise SbrdfError(f"environment option {nm} must be a power of two, got {v}")
        self.method, self.size, self.prefiltered_size, self.diffuse_size = method, size, prefiltered_size, diffuse_size
        self.cosine, self.prefilter_on, self.samples, self.estimator = cosine, prefilter, samples, estimator
        self.xi_border, self.ring_radius, self.line_threshold = xi_border, ring_radius, line_threshold
        self.mc_samples, self.seed = mc_samples, seed
        self.frame_index = 0  # progressive: which block of QMC points the next frame uses
        self._gl: GLResources | None = None  # gl_prepare() makes them, release() drops them
        self.reflectors: set[str] = set()  # materials whose specular lobes another effect draws (prepare)
        self.lightmapped = False  # diffuse from the scene's light maps (prepare)

    # -- protocol: selection --------------------------------------------------------------------------------------

    @staticmethod
    def wanted(scene) -> bool:
        return scene.section("environment") is not None

    @staticmethod
    def options(scene) -> dict:
        return dict(getattr(scene.section("environment"), "options", None) or {})

    @staticmethod
    def check(scene) -> list[str]:
        """Problems :meth:`prepare` would meet, found when the graph is validated: the map is read at a tiny size."""
        env = scene.section("environment")
        if "://" in env.file:
            return []
        try:
            cubemap.load_environment(env.file, env.layout, 2, env.intensity)
        except SbrdfError as e:
            return [str(e)]
        except Exception as e:  # anything the EXR reader raises on a damaged file
            return [f"{env.file}: cannot read the environment map ({type(e).__name__}: {e})"]
        return []

    def prepare(self, scene, materials=None, gl_context=None) -> None:
        """Load the map and build what the method needs (D(N), S maps, the MIP chain)."""
        env = scene.section("environment")
        self.file = env.file
        # a reflector's specular lobes are the mirror effect's (reflected objects occlude the environment there)
        # (and a cube-mapped object's: its cube map holds the environment too, occluded by the room)
        self.reflectors = {scene.objects[k].material for k, o in enumerate(scene.objects)
                           if (o.shape == "plane" and o.params.get("reflector")) or o.params.get("cube_map")}
        # a light-mapped scene's diffuse (the environment's included) comes from the maps: specular only here
        self.lightmapped = bool(getattr(scene, "lightmapped", False))
        logger.info("environment %s (%s, intensity %g): method %s", env.file, env.layout, env.intensity, self.method)
        key = (os.path.abspath(env.file), os.path.getmtime(env.file) if os.path.exists(env.file) else 0, env.layout,
               env.intensity, self.size)
        with _LOCK:
            if key not in _CACHE:
                _CACHE[key] = {"levels": cubemap.mip_chain(cubemap.load_environment(env.file, env.layout, self.size,
                                                                                    env.intensity))}
            self.maps = _CACHE[key]
        use_gl = self.prefilter_on == "gl" or (self.prefilter_on == "auto" and gl_context is not None)
        if use_gl and gl_context is None:
            from sbrdf_lib.gl import context

            gl_context = context()
        how = "gl" if use_gl else "numpy"
        src = self.levels[0]
        wanted = [("D", 1.0, self.diffuse_size)]
        if self.method == "prefiltered-discrete":
            wanted += [(f"S{n:g}", n, self.prefiltered_size) for n in prefilter.EXPONENTS]
        elif self.method == "prefiltered-mip":
            wanted += [(f"M{n:g}", n, s) for n, s in zip(reversed(prefilter.EXPONENTS),
                                                          prefilter.mip_sizes(self.prefiltered_size))]
        with _LOCK:
            todo = [(k, n, s) for k, n, s in wanted if (how, k, s) not in self.maps]
            if (self.method == "mc" or self.method == "progressive") and not self.reflectors:
                todo = [t for t in todo if t[0] != "D"]
            if todo:
                if how == "gl":
                    got = prefilter.prefilter_gl(gl_context, src, [n for _, n, _ in todo], [s for _, _, s in todo])
                    for (k, _, s), m in zip(todo, got):
                        self.maps[(how, k, s)] = m
                else:
                    for k, n, s in todo:
                        self.maps[(how, k, s)] = prefilter.prefilter_numpy(src, n, s)
        self.how = how
        if self.method == "prefiltered-mip":
            pre = {n: self.maps[(how, f"M{n:g}", s)] for n, s in zip(reversed(prefilter.EXPONENTS),
                                                                   prefilter.mip_sizes(self.prefiltered_size))}
            self.mip = prefilter.mip_levels(pre)

    # -- materials with a shading rule of their own (shading maps, seed 002 Eq 3) ------------------------------------

    #: Cube-face size of the directional lights standing for the environment (6·S² of them).
    SURFACE_SIZE = 4

    def surface_lights(self) -> tuple[np.ndarray, np.ndarray]:
        """World directions ``(D, 3)`` and ``L_i dω`` ``(D, 3)``: the environment as D directional lights."""
        level = next(lv for lv in self.levels if lv.shape[1] == min(self.SURFACE_SIZE, self.levels[0].shape[1]))
        dirs, solid = cubemap.face_directions(level.shape[1])
        return dirs.reshape(-1, 3), (level * solid[..., None]).reshape(-1, 3)

    def _surface_radiance(self, material, hits, view_dirs: np.ndarray) -> np.ndarray:
        """Eq 3 as a sum over the environment's directional lights, each through the material's own shading rule."""
        from sbrdf_lib.surface import local_frame

        t, b, n = local_frame(hits.normal, hits.tangent)
        wo_w = -view_dirs
        wo = np.stack([np.einsum("ij,ij->i", t, wo_w), np.einsum("ij,ij->i", b, wo_w), np.einsum("ij,ij->i", n, wo_w)], 1)
        out = np.zeros((len(wo), 3))
        for d, radiance in zip(*self.surface_lights()):
            c = n @ d
            lit = (c > 0) & (wo[:, 2] > 0)
            if lit.any():
                wi = np.stack([t[lit] @ d, b[lit] @ d, c[lit]], 1)
                out[lit] += material.surface.radiance(hits.uv[lit], wi, wo[lit], np.broadcast_to(radiance, wi.shape))
        return out

    def radiance(self, dirs: np.ndarray) -> np.ndarray:
        """The environment's radiance ``(R, 3)`` along world directions ``(R, 3)`` (level 0, bilinear)."""
        return cubemap.sample(self.levels[0], np.asarray(dirs, np.float64))

    @property
    def levels(self) -> list[np.ndarray]:
        return self.maps["levels"]

    def map(self, key: str, size: int) -> np.ndarray:
        return self.maps[(self.how, key, size)]

    # -- protocol: cpu ----------------------------------------------------------------------------------------------

    def cpu_radiance(self, material, hits, view_dirs: np.ndarray, pixels: np.ndarray | None = None) -> np.ndarray:
        """Reflected environment radiance ``(R, 3)`` at hit points seen along ``view_dirs``."""
        from sbrdf_lib.surface import local_frame

        if material.surface is not None:
            return self._surface_radiance(material, hits, view_dirs)
        model = material.model
        n = hits.normal / np.linalg.norm(hits.normal, axis=1, keepdims=True)
        if material.anisotropic:
            t, b, n = local_frame(hits.normal, hits.tangent)
        else:
            t, b = _frame_from_normal(n)
        params = model.unpack(material.lookup(hits.uv))
        wo_w = -view_dirs
        wo = np.stack([np.einsum("ij,ij->i", t, wo_w), np.einsum("ij,ij->i", b, wo_w), np.einsum("ij,ij->i", n, wo_w)], 1)
        front = wo[:, 2] > 0
        out = np.zeros((len(wo), 3))
        if not front.any():
            return out
        idx = np.nonzero(front)[0]
        sub = {k: v[idx] for k, v in params.items()}
        if material.name in self.reflectors:  # diffuse only: the mirror effect adds the specular
            if not self.lightmapped:
                out[idx] = np.asarray(sub["rho_d"]) * cubemap.sample(self.map("D", self.diffuse_size), n[idx])
            return out
        frame = (t[idx], b[idx], n[idx])
        ids = idx if pixels is None else np.asarray(pixels)[idx]
        out[idx] = self._shade(model, sub, wo[idx], frame, ids)
        return out

    def _shade(self, model, params, wo, frame, ids):
        t, b, n = frame
        to_world = lambda v: v[..., :1] * t + v[..., 1:2] * b + v[..., 2:] * n  # noqa: E731
        if self.method in ("mc", "progressive"):
            level0 = self.levels[0]
            incident = lambda d: cubemap.sample(level0, d.reshape(-1, 3)).reshape(d.shape)  # noqa: E731
            return sampling.monte_carlo(model, params, wo, frame, incident, mc_lobes(model, params, wo),
                                        self.mc_samples, self.seed, self.mc_samples * self.frame_index, ids,
                                        specular_only=self.lightmapped)
        kind = lobes.kind(model, self.method)
        out = np.zeros((len(wo), 3))
        if not self.lightmapped:
            out += np.asarray(params["rho_d"]) * cubemap.sample(self.map("D", self.diffuse_size), n)
        if kind == "cosine":
            for lobe in lobes.cosine_lobes(model, params):
                p = lobes.peak(lobe, wo)
                pn = np.linalg.norm(p, axis=1)
                ok = pn > 0
                axis = to_world(p / np.where(ok, pn, 1.0)[:, None])
                e = lobe["exponent"]
                mag = np.exp(np.minimum(e * np.log(np.where(ok, pn, 1.0)), 60.0))
                rho = lobe["rho_s"] * (mag * ok)[:, None]
                if self.method == "sampling":
                    out += self._sample_cosine(rho, axis, e, n)
                    continue
                cos = np.maximum(p[:, 2] / np.where(ok, pn, 1.0), 0) if self.cosine == "normalized" else np.maximum(p[:, 2], 0)
                out += rho * self._specular_map(axis, e) * cos[:, None]
        elif kind == "beckmann":
            out += self._sample_beckmann(model, params, wo, frame)
        return out

    def _specular_map(self, d, n):
        if self.method == "prefiltered-discrete":
            w = prefilter.discrete_weights(n)
            return sum(w[:, k:k + 1] * cubemap.sample(self.map(f"S{e:g}", self.prefiltered_size), d)
                       for k, e in enumerate(prefilter.EXPONENTS))
        lod = len(prefilter.EXPONENTS) - 1 - prefilter.exponent_coordinate(n)
        return cubemap.sample_lod(self.mip, d, lod)

    def _lookup(self, dirs, alpha_u, alpha_v):
        R, K = dirs.shape[:2]
        lod = sampling.footprint_lod(alpha_u, alpha_v, self.samples, dirs, self.size)
        return cubemap.sample_lod(self.levels, dirs.reshape(-1, 3), lod.reshape(-1)).reshape(R, K, 3)

    def _sample_cosine(self, rho, axis, e, n):
        """Ring pattern about p̂ (a cosine lobe is radially symmetric about its peak)."""
        xi = sampling.pattern("ring", self.samples, self.ring_radius)
        tt = sampling.cosine_theta_thresh(e, self.xi_border)
        theta = (1 - xi[None, :, 0]) * tt[:, None]
        dirs = sampling.around(axis, theta, 2 * np.pi * xi[None, :, 1] * np.ones_like(theta))
        cos = np.einsum("rkc,rc->rk", dirs, n)
        valid = cos > 0
        g = np.power(np.maximum(np.cos(theta), 0), e[:, None])
        f = rho[:, None] * g[..., None]
        p = (e[:, None] + 1) / (2 * np.pi) * g
        Li = self._lookup(dirs, tt, tt)
        return sampling.estimate(Li, cos, f, p, valid, self.estimator)

    def _sample_beckmann(self, model, params, wo, frame):
        t, b, n = frame
        m_x, m_y = lobes.slopes(model, params)
        mx, my = m_x[:, None], m_y[:, None]
        K = self.samples
        pats = np.stack([sampling.pattern(k, K, self.ring_radius) for k in sampling.PATTERNS])  # (3, K, 2)
        xi = pats[sampling.choose_pattern(m_x, m_y, self.line_threshold)]  # (R, K, 2)
        phi = sampling.beckmann_phi(xi[..., 1], mx, my)
        theta = (1 - xi[..., 0]) * sampling.theta_thresh(phi, mx, my, self.xi_border)
        h = sampling.half_vector(theta, phi)
        oh = np.einsum("rkc,rc->rk", h, wo)
        wi = sampling.reflect(wo[:, None], h)
        valid = (oh > 0) & (wi[..., 2] > 0)
        f = model.eval(params, wi, np.broadcast_to(wo[:, None], wi.shape)) - np.asarray(params["rho_d"])[:, None]
        p = sampling.beckmann_pdf_angles(theta, phi, oh, mx, my)
        # footprint: lobe centre and its border on the two principal axes (ξ₁ = 0, ξ₂ = 0 and 0.25)
        wc = wo * [-1.0, -1.0, 1.0]
        wu = sampling.reflect(wo, sampling.half_vector(sampling.theta_thresh(0.0, m_x, m_y, self.xi_border), 0.0 * m_x))
        wv = sampling.reflect(wo, sampling.half_vector(sampling.theta_thresh(np.pi / 2, m_x, m_y, self.xi_border),
                                                       np.full_like(m_x, np.pi / 2)))
        au = np.arccos(np.clip(np.sum(wc * wu, 1), -1, 1))
        av = np.arccos(np.clip(np.sum(wc * wv, 1), -1, 1))
        world = wi[..., :1] * t[:, None] + wi[..., 1:2] * b[:, None] + wi[..., 2:] * n[:, None]
        Li = self._lookup(world, au, av)
        return sampling.estimate(Li, wi[..., 2], f, np.where(valid, p, 1.0), valid, self.estimator)

    # -- protocol: gl -----------------------------------------------------------------------------------------------

    def glsl(self, material, exprs: dict) -> tuple[str, list[str]]:
        """Declarations and the statements (in ``main``, after the lights) that add the environment to ``L``."""
        from .glsl import fragment_code

        surface = material.surface
        if surface is not None:  # the environment as directional lights through the material's own rule
            D = len(self.surface_lights()[0])
            loop = ["    for (int k = 0; k < ENV_LIGHTS; ++k) {",
                    "        vec3 d = u_env_light_dir[k];",
                    "        float c = dot(N, d);",
                    "        if (c > 0.0 && wo.z > 0.0) {",
                    "            vec3 wi = vec3(dot(T, d), dot(B, d), c);",
                    f"            L += {surface.glsl_radiance('wi', 'wo', 'u_env_light_radiance[k]')};",
                    "        }", "    }"]
            return (f"const int ENV_LIGHTS = {D};\nuniform vec3 u_env_light_dir[{D}];\n"
                    f"uniform vec3 u_env_light_radiance[{D}];\n", loop)
        if material.name in self.reflectors:  # diffuse only; the mirror effect declares atlas_lod
            if self.lightmapped:
                return "", []
            return ("uniform sampler2D u_env_D;\n",
                    ["    if (wo.z > 0.0) {  // environment: diffuse D(N) of a reflector (sbrdf_envmap)",
                     f"        L += {exprs['rho_d']} * atlas_lod(u_env_D, N, 0.0, {float(self.diffuse_size)!r}, 0.0);",
                     "    }"])
        return fragment_code(self, material, exprs)

    def gl_prepare(self, drawer) -> None:
        from .glsl import GLResources

        self._gl = GLResources(self, drawer.ctx)

    def gl_uniforms(self, prog, first_unit: int) -> int:
        if "u_env_light_dir" in prog:  # a shading-mapped material: lights only, no textures of ours
            dirs, radiance = self.surface_lights()
            prog["u_env_light_dir"].write(dirs.astype("f4").tobytes())
            prog["u_env_light_radiance"].write(radiance.astype("f4").tobytes())
            return 0
        assert self._gl is not None, "gl_prepare() comes first"
        return self._gl.uniforms(prog, first_unit)

    def gl_use(self, first_unit: int) -> int:
        assert self._gl is not None, "gl_prepare() comes first"
        return self._gl.use(first_unit)

    def gl_camera(self, drawer) -> None:
        """The camera moved (a walkthrough): the progressive mode starts its running mean again."""
        self.frame_index = 0

    def gl_frame(self, drawer) -> None:
        """Before each frame of ``drawer`` (a GLScene): the progressive mode advances its block of points."""
        if self.method == "progressive":
            assert self._gl is not None, "gl_prepare() comes first"
            self._gl.frame(drawer, self.frame_index)
            self.frame_index += 1

    def release(self) -> None:
        if self._gl is not None:
            self._gl.release()
            self._gl = None
