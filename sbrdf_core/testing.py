"""Conformance suites a plugin author runs in their own tests.

Subclass the suite for what you contribute, say which contribution it checks,
and pytest collects the inherited tests (the built-in plugins are checked by
exactly these classes, in ``tests/plugins/test_conformance.py``)::

    from sbrdf_core.testing import BRDFModelTests

    class TestMinnaert(BRDFModelTests):
        name = "minnaert"
        configs = [{}]

Each suite finds the contribution through a :class:`~sbrdf_core.registry.Registry`
(installed entry points plus ``plugins``, module paths for a plugin not yet
installed), so it checks what sbrdf will actually load: the protocol of
:mod:`sbrdf_core.contracts`, declared parameters agreeing with ``__init__``,
then behaviour on hard cases (grazing and below-horizon directions, parameter
bounds, all-invalid samples).  Needs ``pytest`` (and ``moderngl`` with an EGL
driver for the GLSL checks, which skip otherwise).
"""

from __future__ import annotations

import warnings
from functools import cached_property
from typing import Any, ClassVar

import numpy as np

__all__ = ["BRDFModelTests", "CaptureSourceTests", "DeviceTests", "FitterTests", "PluginTests", "QuantizerTests", "glsl_eval",
           "glsl_fit_gradient_eval",
           "RendererTests", "strict"]


class strict:
    """No floating-point warning of any kind except underflow (exp(-large) -> 0 is intended)."""

    def __enter__(self):
        self._err = np.errstate(divide="raise", over="raise", invalid="raise", under="ignore")
        self._err.__enter__()
        self._warn = warnings.catch_warnings()
        self._warn.__enter__()
        warnings.simplefilter("error")

    def __exit__(self, *exc):
        self._warn.__exit__(*exc)
        return self._err.__exit__(*exc)


def sph(theta_deg, phi_deg) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


class PluginTests:
    """What every contribution must satisfy: found, importable, protocol, parameters agree.

    Set ``category`` (a :data:`sbrdf_core.plugin.CATEGORIES` key) and
    ``name``; ``plugins`` adds module paths to register (a plugin under
    development that is not installed).
    """

    category: ClassVar[str] = ""
    name: ClassVar[str] = ""
    plugins: ClassVar[tuple[str, ...]] = ()

    @cached_property
    def registry(self):
        from .registry import Registry

        return Registry(extra=self.plugins)

    @cached_property
    def spec(self):
        return self.registry.get(self.category, self.name)

    def create(self, params: dict | None = None) -> Any:
        return self.registry.create(self.category, self.name, params or {})

    def test_implements_its_protocol(self):
        from .contracts import missing

        impl = self.registry.load(self.spec)
        assert missing(self.category, impl) == [], f"{self.spec.impl} lacks members of its protocol"

    def test_declared_parameters_match_the_constructor(self):
        from .registry import signature_problems

        impl = self.registry.load(self.spec)
        problems = signature_problems(impl, self.spec.params)
        assert problems == [], problems

    def test_every_declared_parameter_is_documented(self):
        undocumented = [p.name for p in self.spec.params if not p.doc]
        assert not undocumented, f"parameters without a doc string: {undocumented}"


class BRDFModelTests(PluginTests):
    """The BRDF-model contract: Jacobian, finiteness at the bounds and at grazing, reciprocity, fit form, GLSL.

    ``configs`` are the model configurations to check (each one a
    ``model_params`` mapping).
    """

    category = "brdf-model"
    configs: ClassVar[list[dict]] = [{}]
    #: Direction pairs of the GLSL check.
    glsl_pairs: ClassVar[int] = 256

    def glsl_agreement(self, model) -> float:
        """Fraction of the GLSL check's pairs that must agree with ``eval`` (all of them, unless a model's lookup
        can land in a neighbouring table bin in float32, as a tabulated model's nearest lookup does)."""
        return 1.0

    def models(self):
        return [self.create(cfg) for cfg in self.configs]

    def test_analytic_jacobian_matches_central_differences(self):
        from .brdf import BRDFModel
        from .brdf_checks import hemisphere_directions

        for model in self.models():
            for m in (model, model.fit_form()):
                rng = np.random.default_rng(7)
                T, S = 5, 40
                params = m.random_guess(rng, T)
                wi, wo = hemisphere_directions(rng, (T, S)), hemisphere_directions(rng, (T, S))
                wi[:, :4, 2] *= -1  # a few pairs below the horizon
                with strict():
                    J = m.jacobian(params, wi, wo)
                assert J.shape == (T, S, 3, m.size)
                J_fd = BRDFModel.jacobian(m, params, wi, wo)
                scale = np.abs(J_fd).max(axis=(0, 1, 2), keepdims=True)
                bad = np.abs(J - J_fd) > 1e-4 * np.abs(J_fd) + 1e-6 * scale + 1e-12
                assert not bad.any(), f"{m.name}: Jacobian columns {np.flatnonzero(bad.any(axis=(0, 1, 2)))} disagree"
                assert np.all(J[:, :4] == 0.0)

    def test_fit_kernel_is_the_fit_forms_eval_and_jacobian(self):
        """A model's optional ``fit_kernel`` (what the fitting engine compiles) gives the fit form's ``eval`` and
        ``jacobian`` at every direction pair, pairs below the horizon included (the kernel run as plain Python)."""
        from .brdf_checks import hemisphere_directions

        for model in self.models():
            form = model.fit_form()
            kernel = getattr(form, "kernel", None)
            if kernel is None:
                continue
            kernel = getattr(kernel, "py_func", kernel)
            rng = np.random.default_rng(5)
            T, S = 4, 24
            params = form.from_model(model.random_guess(rng, T))
            x = form.pack(params)
            wi, wo = hemisphere_directions(rng, (T, S)), hemisphere_directions(rng, (T, S))
            wi[:, :3, 2] *= -1
            f_ref, J_ref = form.eval(params, wi, wo), form.jacobian(params, wi, wo)
            cfg = np.asarray(form.kernel_config(), np.float64)
            f, J = np.empty(f_ref.shape[-1]), np.empty((f_ref.shape[-1], x.shape[1]))
            for t in range(T):
                for s_ in range(S):
                    kernel(x[t], cfg, wi[t, s_], wo[t, s_], f, J)
                    np.testing.assert_allclose(f, f_ref[t, s_], rtol=1e-9, atol=1e-12, err_msg=model.name)
                    np.testing.assert_allclose(J, J_ref[t, s_], rtol=1e-7, atol=1e-9 * max(1.0, np.abs(J_ref).max()),
                                               err_msg=model.name)

    def test_finite_at_parameter_bounds_and_zero_below_horizon(self):
        theta = np.array([0.0, 45.0, 85.0, 89.0, 89.99, 90.0, 95.0, 180.0])
        ti, to = np.meshgrid(theta, theta, indexing="ij")
        wi, wo = sph(ti.ravel(), 30.0)[None], sph(to.ravel(), 210.0)[None]
        below = (wi[..., 2] <= 0) | (wo[..., 2] <= 0)
        for model in self.models():
            for m in (model, model.fit_form()):
                for pick in ("lo", "hi", "default", "typical_lo", "typical_hi"):
                    params = {}
                    for p in m.parameters:
                        v = {"lo": p.bounds[0], "hi": p.bounds[1], "default": p.default,
                             "typical_lo": p.typical[0], "typical_hi": p.typical[1]}[pick]
                        params[p.name] = np.full((1, p.channels), float(np.clip(v, -1e6, 1e6)))
                    with strict():
                        f, J = m.eval(params, wi, wo), m.jacobian(params, wi, wo)
                    assert np.isfinite(f).all() and np.isfinite(J).all(), f"{m.name} at {pick} bounds"
                    assert np.all(f >= 0.0)
                    assert np.all(f[below] == 0.0) and np.all(J[below] == 0.0)

    def test_reciprocal(self):
        from .brdf_checks import reciprocity_error

        for model in self.models():
            params = model.random_guess(np.random.default_rng(5), 16)
            assert reciprocity_error(model, params, n_pairs=128).max() < 1e-12

    def test_fit_form_round_trip_is_the_same_brdf(self):
        from .brdf_checks import hemisphere_directions

        for model in self.models():
            fit = model.fit_form()
            rng = np.random.default_rng(3)
            params = model.random_guess(rng, 8)
            wi, wo = hemisphere_directions(rng, (8, 64)), hemisphere_directions(rng, (8, 64))
            f = model.eval(params, wi, wo)
            np.testing.assert_allclose(fit.eval(fit.from_model(params), wi, wo), f, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(model.eval(fit.to_model(fit.from_model(params)), wi, wo), f,
                                       rtol=1e-9, atol=1e-12)

    def test_constrain_is_a_projection(self):
        """Constrained parameters stay inside the declared bounds and constraining twice changes nothing."""
        from .types import Limits

        for model in self.models():
            form = model.fit_form()
            T = 8
            params = form.random_guess(np.random.default_rng(9), T)
            limits = Limits(peak=np.full(T, 5.0), resolution=np.full(T, np.radians(5.0)), growth=1.0,
                            peak_cosine=np.full(T, 5.0))
            once, _ = form.constrain(params, limits)
            lo, hi = form.bounds()
            x = form.pack(once)
            assert np.all(np.isfinite(x)) and np.all(x >= lo - 1e-9) and np.all(x <= hi + 1e-9)
            twice, _ = form.constrain(once, limits)
            for k in once:
                np.testing.assert_allclose(twice[k], once[k], rtol=1e-6, atol=1e-9)

    def test_project_kernel_is_the_fit_forms_constrain(self):
        """A fit form's optional ``project_kernel`` (what the fitting engine projects every iterate with, inside
        the box ``limit_box`` makes) gives the fit form's ``constrain``, on random points and binding limits."""
        from .types import Limits

        checked = 0
        for model in self.models():
            form = model.fit_form()
            kernel = getattr(form, "project_kernel", None)
            if kernel is None:
                continue
            T, rng = 64, np.random.default_rng(4)
            x = form.pack(form.random_guess(rng, T))
            x[::3] *= 3.0  # beyond the typical ranges: brighter and sharper than the limits allow
            lo, hi = form.bounds()
            x = np.clip(x, lo, hi)
            peak = np.exp(rng.uniform(np.log(0.05), np.log(20.0), T))
            for limits in (Limits(peak=peak, resolution=np.radians(rng.uniform(0.3, 20.0, T))), Limits(peak=peak),
                           Limits(resolution=np.full(T, np.radians(4.0)), max_theta=np.radians(80.0))):
                want = form.pack(form.constrain(form.unpack(x.copy()), limits)[0])
                box_lo = np.broadcast_to(lo, x.shape).copy()
                box_hi = np.broadcast_to(hi, x.shape).copy()
                box = getattr(form, "limit_box", None)
                if box is not None:
                    box_lo, box_hi = box(limits, box_lo, box_hi)
                lim = np.ascontiguousarray(form.project_limits(limits, T), np.float64)
                cfg = np.asarray(form.kernel_config(), np.float64) if hasattr(form, "kernel_config") else np.zeros(0)
                got = x.copy()
                for t in range(T):
                    kernel(got[t], cfg, lim[t], box_lo[t], box_hi[t])
                np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12, err_msg=model.name)
            checked += 1
        if not checked:
            import pytest

            pytest.skip("no model here has a project_kernel (optional)")

    def test_glsl_compiles_and_matches_numpy(self):
        """The model's GLSL, called through ``glsl_call`` with each parameter a uniform, against ``eval``."""
        import pytest

        moderngl = pytest.importorskip("moderngl")
        try:
            ctx = moderngl.create_context(standalone=True, backend="egl")
        except Exception as e:  # no EGL driver: nothing to compile against
            pytest.skip(f"no EGL context: {e}")
        from .brdf_checks import hemisphere_directions

        fbo = ctx.simple_framebuffer((1, 1))
        fbo.use()
        try:
            for model in self.models():
                rng = np.random.default_rng(11)
                S = self.glsl_pairs
                wi, wo = hemisphere_directions(rng, (1, S))[0], hemisphere_directions(rng, (1, S))[0]
                wi[:8, 2] *= -1
                params = model.random_guess(rng, 1)
                expect = model.eval(params, wi[None], wo[None])[0]
                got = glsl_eval(ctx, model, params, wi, wo)
                atol = 1e-5 * max(np.abs(expect).max(), 1e-30)
                need = self.glsl_agreement(model)
                if need >= 1.0:
                    np.testing.assert_allclose(got, expect, rtol=2e-3, atol=atol)
                else:
                    close = np.isclose(got, expect, rtol=2e-3, atol=atol).all(axis=1)
                    assert close.mean() >= need, (model.name, close.mean(), need)
                assert np.all(got[:8] == 0.0)
        finally:
            fbo.release()
            ctx.release()

    def _compute_models(self, member: str, has=None):
        """The models providing the optional GLSL ``member`` (``has(model)`` where given) and an EGL context with
        compute shaders (GL 4.3), or a skip saying which is missing."""
        import pytest

        from .contracts import optional

        models = [m for m in self.models() if (has(m) if has else optional(m, member, "brdf-model") is not None)]
        if not models:
            pytest.skip(f"the model has no {member} (optional)")
        moderngl = pytest.importorskip("moderngl")
        try:
            return models, moderngl.create_context(standalone=True, backend="egl", require=430)
        except Exception as e:  # no EGL driver or no GL 4.3 compute shaders
            pytest.skip(f"no EGL context with compute shaders: {e}")

    def test_glsl_fit_gradient_matches_numpy(self):
        """The GLSL translated from the fit form's ``fit_kernel`` (:mod:`sbrdf_core.engine_glsl`: value and ∂f/∂x in
        the fit form, what ``lm-gl`` runs) against the fit form's ``eval`` and ``jacobian``, in a compute shader (float32: 0.5 % of each value and 0.1 % of the column's largest, as log of a
        near-1 dot product loses digits): random parameters, random directions with a few below the horizon, and
        for shape parameters that are exponents, sharp lobes (n up to 10⁴) probed near their peak."""
        from .brdf_checks import hemisphere_directions
        from .engine_glsl import fit_gradient_glsl

        models, ctx = self._compute_models("fit_kernel", lambda m: fit_gradient_glsl(m) is not None)

        try:
            for model in models:
                form = model.fit_form()
                rng = np.random.default_rng(13)
                cases = [form.random_guess(rng, 1) for _ in range(3)]
                sharp = form.random_guess(rng, 1)
                logs = [p.name for p in form.parameters if "exponent" in p.name]
                for name in logs:  # n = 10⁴: value and gradient still agree where the lobe is lit
                    sharp[name] = np.full((1, 1), np.log(1e4))
                cases.append(sharp)
                for params in cases:
                    S = self.glsl_pairs
                    wi, wo = hemisphere_directions(rng, (1, S))[0], hemisphere_directions(rng, (1, S))[0]
                    wo[: S // 2] = wi[: S // 2] * np.array([-1.0, -1.0, 1.0]) + rng.normal(0, 3e-3, (S // 2, 3))
                    wo[: S // 2, 2] = np.abs(wo[: S // 2, 2])
                    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
                    wi[:8, 2] *= -1
                    wi[8:12, 2] = 1e-4  # grazing
                    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
                    with np.errstate(all="ignore"):
                        f = form.eval(params, wi[None], wo[None])[0]
                        J = form.jacobian(params, wi[None], wo[None])[0]  # (S, 3, K)
                    got_f, got_J = glsl_fit_gradient_eval(ctx, model, form.pack(params)[0], wi, wo)
                    lit = np.abs(f).max()
                    np.testing.assert_allclose(got_f, f, rtol=5e-3, atol=1e-5 * max(lit, 1e-30), err_msg=model.name)
                    scale = np.maximum(np.abs(J).max(axis=(0, 1)), 1e-30)  # per column
                    err = np.abs(got_J - J) - 5e-3 * np.abs(J)
                    assert np.all(err <= 1e-3 * scale), (model.name, np.max(err / scale, axis=(0, 1)))
                    assert np.all(got_J[:8] == 0.0) and np.all(got_f[:8] == 0.0)
        finally:
            ctx.release()

    def test_glsl_fit_constrain_matches_numpy(self):
        """The optional ``glsl_fit_constrain`` (the fit form's projection onto the texel's limits) against the fit
        form's numpy ``constrain``, in a compute shader: random fit-form points with hard cases (exponents to 10⁴,
        the finest roughness, magnitudes 30× too bright or 0, |C| at its bound) under random per-texel limits that
        bind (a zero peak, resolutions below the floor and of π/2 among them), each bound on and off (growth None
        or set, peak_cosine None or set).  Float32: 2·10⁻⁴ + 2·10⁻³
        relative per parameter (log parameters: the bisection's last bracket, 1.2·10⁻⁴, plus round-off)."""
        from .types import Limits

        models, ctx = self._compute_models("glsl_fit_constrain")
        try:
            for model in models:
                form = model.fit_form()
                rng = np.random.default_rng(17)
                T = 120
                x = form.pack(form.random_guess(rng, T))
                lo, hi = form.bounds()
                for p in form.parameters:
                    s = form.slices()[p.name]
                    if "exponent" in p.name:  # sharp lobes, to n = 10⁴ and beyond
                        x[::4, s] = np.log(1e4)
                        x[1::4, s] = rng.uniform(np.log(1e3), np.log(2e4), (len(x[1::4]), p.channels))
                    elif p.name.startswith("log_"):  # the finest roughness the form allows
                        x[::5, s] = lo[s]
                    elif p.magnitude:
                        x[2::5, s] *= 30.0
                        x[3::7, s] = 0.0
                    elif p.name.startswith("c_"):
                        x[5::8, s] = hi[s] * rng.choice([-1.0, 1.0], (len(x[5::8]), p.channels))
                x = np.clip(x, lo, hi).astype(np.float32).astype(np.float64)
                peak = np.exp(rng.uniform(np.log(0.05), np.log(20.0), T))
                resolution = np.radians(rng.uniform(0.3, 20.0, T))
                cosine = peak * rng.uniform(0.05, 1.0, T)
                peak[::11], cosine[::11] = 0.0, 0.0  # a texel with no support: no lobe at all
                resolution[::13], resolution[1::13] = 1e-5, np.pi / 2  # below the floor, and nothing resolved
                sets = [Limits(peak=peak, resolution=resolution, max_theta=np.radians(80.0)),
                        Limits(peak=peak, resolution=resolution, growth=2.0, peak_cosine=cosine),
                        Limits(growth=1.0, max_theta=np.radians(85.0)),
                        Limits(peak=peak, peak_cosine=cosine, max_theta=np.radians(60.0)),
                        Limits(resolution=resolution),
                        Limits()]
                for limits in sets:
                    with np.errstate(all="ignore"):
                        want, moved = form.constrain(form.unpack(x.copy()), limits)
                    want = form.pack(want)
                    got = glsl_fit_constrain_eval(ctx, model, x, limits)
                    bad = np.abs(got - want) > 2e-4 + 2e-3 * np.abs(want)
                    assert not bad.any(), (model.name, limits, np.argwhere(bad)[:5], got[bad][:5], want[bad][:5])
                    if limits.peak is not None:  # the case binds: the projection moves many texels
                        assert np.mean(moved) > 0.2, (model.name, np.mean(moved))
        finally:
            ctx.release()


def glsl_fit_constrain_eval(ctx, model, x: np.ndarray, limits) -> np.ndarray:
    """``model.glsl_fit_constrain()`` on packed fit-form rows ``x`` ``(T, K)`` under per-texel ``limits``, one texel
    per invocation of a GL 4.3 compute shader: the projected rows ``(T, K)``."""
    from .constraints_glsl import LIMITS_STRIDE, pack_limits, scalars

    T, K = x.shape
    cs = ctx.compute_shader(
        "#version 430\nlayout(local_size_x = 64) in;\n"
        "layout(std430, binding = 0) buffer X { float xs[]; };\n"
        "layout(std430, binding = 1) readonly buffer Limits { float lim[]; };\n"
        f"uniform int u_count;\nuniform float u_growth;\nuniform float u_max_theta;\n{model.glsl_fit_constrain()}\n"
        "void main() {\n"
        "    int t = int(gl_GlobalInvocationID.x);\n"
        "    if (t >= u_count) return;\n"
        f"    float x[{K}];\n    for (int k = 0; k < {K}; ++k) x[k] = xs[t * {K} + k];\n"
        f"    int o = t * {LIMITS_STRIDE};\n"
        "    brdf_fit_constrain(x, lim[o], lim[o + 1], lim[o + 2], u_growth, u_max_theta);\n"
        f"    for (int k = 0; k < {K}; ++k) xs[t * {K} + k] = x[k];\n"
        "}\n")
    growth, max_theta = scalars(limits)
    cs["u_count"].value = T
    for name, value in (("u_growth", growth), ("u_max_theta", max_theta)):
        if name in cs:
            cs[name].value = value
    xs = ctx.buffer(np.ascontiguousarray(x, "f4").tobytes())
    lim = ctx.buffer(pack_limits(limits, T).tobytes())
    xs.bind_to_storage_buffer(0)
    lim.bind_to_storage_buffer(1)
    cs.run((T + 63) // 64)
    out = np.frombuffer(xs.read(), dtype="f4").reshape(T, K).astype(np.float64)
    for obj in (cs, xs, lim):
        obj.release()
    return out


def glsl_eval(ctx, model, params: dict, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Evaluate ``model.glsl()`` on ``(S, 3)`` pairs by transform feedback, one texel's parameters as uniforms."""
    import moderngl

    def gtype(p):
        return "vec3" if p.channels == 3 else "float"

    decl = " ".join(f"uniform {gtype(p)} u_{p.name};" for p in model.parameters)
    call = model.glsl_call("in_wi", "in_wo", {p.name: f"u_{p.name}" for p in model.parameters})
    vs = f"#version 330\nin vec3 in_wi;\nin vec3 in_wo;\nout vec3 f;\n{decl}\n{model.glsl()}\nvoid main() {{ f = {call}; }}\n"
    prog = ctx.program(vertex_shader=vs, varyings=["f"])
    for p in model.parameters:
        if f"u_{p.name}" in prog:
            prog[f"u_{p.name}"].write(np.asarray(params[p.name][0], dtype="f4").tobytes())
    from .contracts import optional

    textures = []  # material-wide tables a model samples (tabulated, separable), bound as the gl renderer binds them
    for unit, (uniform, array) in enumerate(((optional(model, "gl_textures", "brdf-model") or dict)() or {}).items()):
        a = np.ascontiguousarray(array, np.float32)
        t = ctx.texture((a.shape[1], a.shape[0]), a.shape[2], a.tobytes(), dtype="f4")
        t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        t.use(location=unit)
        if uniform in prog:
            prog[uniform].value = unit
        textures.append(t)
    vbo = ctx.buffer(np.concatenate([wi, wo], axis=1).astype("f4").tobytes())
    out = ctx.buffer(reserve=wi.shape[0] * 12)
    vao = ctx.vertex_array(prog, [(vbo, "3f 3f", "in_wi", "in_wo")])
    vao.transform(out, mode=moderngl.POINTS, vertices=wi.shape[0])
    res = np.frombuffer(out.read(), dtype="f4").reshape(-1, 3).astype(np.float64)
    for obj in (vao, vbo, out, prog, *textures):
        obj.release()
    return res


def glsl_fit_gradient_eval(ctx, model, x: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``brdf_fit_gradient`` translated from ``model``'s fit kernel (:func:`~sbrdf_core.engine_glsl.fit_gradient_glsl`)
    on ``(S, 3)`` pairs at packed fit-form ``x`` ``(K,)`` in a GL 4.3 compute shader: ``f (S, 3)`` and ``J (S, 3, K)``."""
    from .engine_glsl import fit_gradient_glsl

    K, S = x.shape[0], wi.shape[0]
    cs = ctx.compute_shader(
        "#version 430\nlayout(local_size_x = 64) in;\n"
        "layout(std430, binding = 0) readonly buffer Dirs { float dirs[]; };\n"
        "layout(std430, binding = 1) writeonly buffer Out { float outv[]; };\n"
        f"uniform float u_x[{K}];\nuniform int u_count;\n{fit_gradient_glsl(model)}\n"
        "void main() {\n"
        "    int s = int(gl_GlobalInvocationID.x);\n"
        "    if (s >= u_count) return;\n"
        "    vec3 wi = vec3(dirs[6 * s], dirs[6 * s + 1], dirs[6 * s + 2]);\n"
        "    vec3 wo = vec3(dirs[6 * s + 3], dirs[6 * s + 4], dirs[6 * s + 5]);\n"
        f"    float x[{K}];\n    for (int k = 0; k < {K}; ++k) x[k] = u_x[k];\n"
        f"    vec3 g[{K}];\n    vec3 f = brdf_fit_gradient(wi, wo, x, g);\n"
        f"    int o = s * {3 * (K + 1)};\n"
        "    for (int c = 0; c < 3; ++c) {\n"
        f"        outv[o + c * {K + 1}] = f[c];\n"
        f"        for (int k = 0; k < {K}; ++k) outv[o + c * {K + 1} + 1 + k] = g[k][c];\n"
        "    }\n}\n")
    cs["u_x"].write(np.asarray(x, "f4").tobytes())
    cs["u_count"].value = S
    dirs = ctx.buffer(np.concatenate([wi, wo], axis=1).astype("f4").tobytes())
    out = ctx.buffer(reserve=S * 3 * (K + 1) * 4)
    dirs.bind_to_storage_buffer(0)
    out.bind_to_storage_buffer(1)
    cs.run((S + 63) // 64)
    res = np.frombuffer(out.read(), dtype="f4").reshape(S, 3, K + 1).astype(np.float64)
    for obj in (cs, dirs, out):
        obj.release()
    return res[..., 0], res[..., 1:]


class FitterTests(PluginTests):
    """The fitter contract: recovers its own model from clean data; empty and NaN data give defaults, not NaN.

    ``params`` are the fitter's parameters for the checks (a model and its
    configuration, usually).
    """

    category = "fitter"
    params: ClassVar[dict] = {}
    #: Relative RMS a fit of noise-free data from the same model must reach.
    tolerance: ClassVar[float] = 0.05

    def _problem(self, T=6, S=96, seed=1):
        from .brdf_checks import hemisphere_directions

        fitter = self.create(self.params)
        fitter_bind(fitter, self.registry)
        model = self.registry.create("brdf-model", fitter.model_name, dict(fitter.model_config))
        rng = np.random.default_rng(seed)
        truth = model.defaults(T) if not hasattr(model, "random_guess") else model.random_guess(rng, T)
        wi, wo = hemisphere_directions(rng, (T, S)), hemisphere_directions(rng, (T, S))
        wi[..., 2] = np.maximum(wi[..., 2], 0.05)
        wo[..., 2] = np.maximum(wo[..., 2], 0.05)
        wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
        wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
        f = model.eval(truth, wi, wo)
        return fitter, model, f, np.ones((T, S), bool), wi, wo

    @staticmethod
    def _truth(model, T, seed=1):
        """The parameters :meth:`_problem`'s samples are drawn from: its first draw of the same seed."""
        rng = np.random.default_rng(seed)
        return model.defaults(T) if not hasattr(model, "random_guess") else model.random_guess(rng, T)

    def test_result_has_one_row_per_texel(self):
        fitter, model, f, valid, wi, wo = self._problem()
        res = fitter.fit(model, f, valid, wi, wo)
        T = f.shape[0]
        assert res.rms.shape == (T,) and res.samples.shape == (T,)
        for p in model.parameters:
            assert res.params[p.name].shape == (T, p.channels)
            assert np.isfinite(res.params[p.name]).all()

    def test_fits_clean_data_of_its_own_model(self):
        fitter, model, f, valid, wi, wo = self._problem()
        res = fitter.fit(model, f, valid, wi, wo)
        scale = np.sqrt(np.mean(f ** 2, axis=(1, 2)))
        assert np.median(res.rms / np.maximum(scale, 1e-12)) < self.tolerance

    def test_skipping_the_rms_changes_no_parameter(self):
        """``rms=False`` (what the Fit node passes) gives the same parameters without the training RMS, and
        ``rms`` None or one value per texel."""
        fitter, model, f, valid, wi, wo = self._problem()
        full, bare = fitter.fit(model, f, valid, wi, wo), fitter.fit(model, f, valid, wi, wo, rms=False)
        assert bare.rms is None or np.shape(bare.rms) == (f.shape[0],)
        for p in model.parameters:
            np.testing.assert_array_equal(bare.params[p.name], full.params[p.name], err_msg=p.name)

    def test_usable_samples_are_fitted_as_the_raw_ones(self):
        """``usable=True`` with samples :func:`~sbrdf_core.nodes.fit.usable` cleaned (what the Fit node passes)
        gives the parameters the raw samples give, a NaN and an inf among them."""
        from sbrdf_core.nodes.fit import usable

        fitter, model, f, valid, wi, wo = self._problem()
        f = np.array(f, dtype=np.float64)
        f[0, 0, 1], f[-1, 1, 0] = np.nan, np.inf
        clean, ok = usable(f, valid, np.float64)
        raw, checked = fitter.fit(model, f, valid, wi, wo), fitter.fit(model, clean, ok, wi, wo, usable=True)
        np.testing.assert_array_equal(checked.samples, raw.samples)
        for p in model.parameters:
            np.testing.assert_array_equal(checked.params[p.name], raw.params[p.name], err_msg=p.name)

    def test_refines_from_a_given_solution(self):
        """``initial`` (what the Fit node passes when a neighbour's solution fits a texel better): the fit from the
        true parameters of clean data stays a fit of them, whether the fitter refines from it or ignores it."""
        fitter, model, f, valid, wi, wo = self._problem()
        truth = {k: np.asarray(v, np.float64) for k, v in model.unpack(model.pack(
            self._truth(model, f.shape[0]))).items()}
        res = fitter.fit(model, f, valid, wi, wo, initial=truth)
        scale = np.sqrt(np.mean(f ** 2, axis=(1, 2)))
        assert np.median(res.rms / np.maximum(scale, 1e-12)) < self.tolerance
        for p in model.parameters:
            assert res.params[p.name].shape == (f.shape[0], p.channels)

    def test_no_valid_sample_gives_finite_defaults(self):
        fitter, model, f, valid, wi, wo = self._problem(T=3)
        f = np.full_like(f, np.nan)
        res = fitter.fit(model, f, np.zeros_like(valid), wi, wo)
        for p in model.parameters:
            assert np.isfinite(res.params[p.name]).all(), f"{p.name} not finite with no valid samples"
        assert np.all(res.samples == 0)


def fitter_bind(obj, registry) -> None:
    from .contracts import optional

    bind = optional(obj, "bind", "fitter")
    if bind is not None:
        bind(registry)


class QuantizerTests(PluginTests):
    """The quantizer contract: encode then decode returns finite maps of every parameter, close to the input."""

    category = "quantizer"
    params: ClassVar[dict] = {}
    model: ClassVar[tuple[str, dict]] = ("lambert", {})
    #: Largest relative error of a decoded parameter map.
    tolerance: ClassVar[float] = 0.05

    def test_round_trip(self):
        import dask.array as da

        q = self.create(self.params)
        fitter_bind(q, self.registry)
        model = self.registry.create("brdf-model", *self.model)
        rng = np.random.default_rng(2)
        V = U = 8
        params = {k: v.reshape(V, U, -1) for k, v in model.random_guess(rng, V * U).items()}
        lazy = {k: da.from_array(v, chunks=(4, 4, v.shape[-1])) for k, v in params.items()}
        enc = q.encode(lazy, model)
        textures = {k: np.asarray(da.asarray(t).compute()) for k, t in enc.textures.items()}
        scale = {k: np.asarray(da.asarray(s).compute()) for k, s in enc.scale.items()}
        bias = {k: np.asarray(da.asarray(b).compute()) for k, b in enc.bias.items()}
        decoded = self.registry.create(self.category, self.name, {}).decode(textures, scale, bias, model)
        for p in model.parameters:
            got = np.asarray(decoded[p.name], dtype=np.float64).reshape(V, U, -1)
            assert np.isfinite(got).all()
            span = np.ptp(params[p.name]) or 1.0
            assert np.abs(got - params[p.name]).max() <= self.tolerance * span, p.name


class CaptureSourceTests(PluginTests):
    """The capture-source contract: ``describe`` matches what ``read_pose`` returns."""

    category = "capture"
    params: ClassVar[dict] = {}

    def test_poses_match_the_description(self):
        src = self.create(self.params)
        fitter_bind(src, self.registry)
        desc = src.describe()
        image, valid = src.read_pose(0)
        assert image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.float32
        assert valid.shape == image.shape[:2] and valid.dtype == bool
        assert np.isfinite(image[valid]).all()
        assert len(desc.light_pos) >= 1 and (desc.height, desc.width) == image.shape[:2]


class DeviceTests(PluginTests):
    """The motor-controller contract over a real serial link to the driver's own pty simulator.

    The simulator is the driver's ``simulator`` attribute (``"module:Class"``,
    the one the ``gonio`` capture starts for ``port: sim``); its port is
    passed as ``port``.  ``targets`` are reachable positions per axis.
    """

    category = "device"
    params: ClassVar[dict] = {}
    targets: ClassVar[dict[str, float]] = {}
    tolerance: ClassVar[float] = 0.05

    def _simulator(self):
        from .registry import import_path

        impl = self.registry.load(self.spec)
        path = getattr(impl, "simulator", None)
        assert path, f"{self.spec.impl} names no simulator (class attribute 'simulator'); test it against hardware"
        return import_path(path)()

    def test_moves_report_where_they_arrived(self):
        with self._simulator() as sim:
            dev = self.create({**self.params, "port": sim.port})
            try:
                reached = dev.move_to(**self.targets)
                where = dev.position()
                for axis, target in self.targets.items():
                    assert abs(reached[axis] - target) <= self.tolerance
                    assert abs(where[axis] - target) <= self.tolerance
                dev.stop()  # safe at rest
            finally:
                dev.close()

    def test_a_silent_port_is_a_clear_error(self):
        """Nothing answers: construction or the first exchange fails naming the port, never hangs or half-works."""
        import pytest

        from .errors import SbrdfError

        with self._simulator() as sim:
            port = sim.port
            sim.close() if hasattr(sim, "close") else None
        with pytest.raises((SbrdfError, OSError)) as err:
            dev = self.create({**self.params, "port": port, **({"timeout_s": 0.2} if any(
                p.name == "timeout_s" for p in self.spec.params) else {})})
            dev.position()
        assert port in str(err.value) or "port" in str(err.value).lower()


class RendererTests(PluginTests):
    """The renderer contract: a small random material renders to a finite, non-negative image.

    ``params`` are the renderer's (a ``scene`` path for scene renderers);
    ``model`` the BRDF model of the material.
    """

    category = "renderer"
    params: ClassVar[dict] = {}
    model: ClassVar[tuple[str, dict]] = ("lambert", {})

    def test_renders_a_finite_image(self):
        import dask
        import dask.array as da

        from .contracts import optional
        from .types import Material

        r = self.create(self.params)
        bind = optional(r, "bind", "renderer")
        if bind is not None:
            bind(self.registry)
        model = self.registry.create("brdf-model", *self.model)
        V = U = 16
        params = {k: da.from_array(v.reshape(V, U, -1), chunks=(8, 8, v.shape[-1]))
                  for k, v in model.random_guess(np.random.default_rng(4), V * U).items()}
        material = Material(model, params, (V, U), (50.0, 50.0), "memory://conformance", None, None, [])
        prepare = optional(r, "prepare", "renderer")
        if prepare is not None:
            lazy = prepare(material)
            prepared = dict(zip(lazy, dask.compute(*lazy.values(), scheduler="sync")))
            result = r.render(material, prepared=prepared)
        else:
            result = r.render(material)
        image = np.asarray(da.asarray(result.image).compute(scheduler="sync") if hasattr(result.image, "dask")
                           else result.image)
        assert image.ndim == 3 and image.shape[2] == 3
        assert np.isfinite(image).all() and (image >= 0).all()
        assert image.max() > 0, "the material is lit and in view: the image should not be black"


# ---------------------------------------------------------------------------
# Frame cameras
# ---------------------------------------------------------------------------


class CameraTests(PluginTests):
    """The frame-camera contract (:class:`~sbrdf_core.contracts.FrameCamera`), against the driver's emulator.

    ``params`` open the emulated (or seam-backed) camera; override
    :meth:`open_camera` when the emulator needs more than parameters (an
    environment variable, a fake library).  ``exposure_s`` is a time the
    camera accepts.  Errors are checked by class name
    (``ExposureRefused``, ``CameraLost``), so the suite imports no driver code.
    """

    category = "device"
    params: ClassVar[dict] = {}
    exposure_s: ClassVar[float] = 0.01

    def open_camera(self) -> Any:
        return self.create(self.params)

    def test_info_names_the_camera_and_its_settings(self):
        cam = self.open_camera()
        try:
            info = cam.info()
            for key in ("vendor", "model", "serial", "pixel_format", "bit_depth", "linear", "gain_db", "black_level",
                        "trigger", "white_balance", "width", "height"):
                assert key in info, f"info() lacks {key!r}"
            assert info["white_balance"] == "off"
            assert info["width"] > 0 and info["height"] > 0 and 8 <= info["bit_depth"] <= 16
        finally:
            cam.close()

    def test_frames_are_full_scale_rgb_codes_of_the_declared_size(self):
        cam = self.open_camera()
        try:
            used = cam.set_exposure(self.exposure_s)
            assert abs(used - self.exposure_s) <= 0.05 * self.exposure_s, (used, self.exposure_s)
            frame = cam.grab(pose_id=0, exposure_index=0)
            info = cam.info()
            assert frame.shape == (info["height"], info["width"], 3)
            assert frame.dtype == (np.uint8 if info["bit_depth"] == 8 else np.uint16)
            if info["bit_depth"] not in (8, 16):  # MSB-aligned: the unused low bits are zero
                assert not (frame & ((1 << (16 - info["bit_depth"])) - 1)).any()
        finally:
            cam.close()

    def test_an_exposure_outside_the_range_is_refused_before_the_camera_sees_it(self):
        import pytest

        cam = self.open_camera()
        try:
            lo, hi = cam.exposure_range_s()
            assert 0 < lo <= hi
            with pytest.raises(Exception) as err:
                cam.set_exposure(hi * 10 + 1.0)
            assert type(err.value).__name__ == "ExposureRefused" and "range" in str(err.value)
        finally:
            cam.close()

    def test_close_is_idempotent_and_a_closed_camera_is_lost(self):
        import pytest

        cam = self.open_camera()
        cam.close()
        cam.close()
        with pytest.raises(Exception) as err:
            cam.grab()
        assert type(err.value).__name__ == "CameraLost"


__all__ += ["CameraTests"]
