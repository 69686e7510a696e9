"""The fitting engine (``sbrdf_core.engine``): its kernel cache, its threads, and what lm builds on it."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pytest

from sbrdf_core import engine
from sbrdf_core.registry import Registry


def _lambert_problem(T=64, S=40, seed=0):
    model = Registry().create("brdf-model", "lambert", {})
    form = model.fit_form()
    rng = np.random.default_rng(seed)
    wi = np.tile([0.0, 0.0, 1.0], (T, S, 1))
    wo = np.tile([0.0, 0.0, 1.0], (T, S, 1))
    f = rng.uniform(0.1, 0.3, (T, 1, 3)) + 0.01 * rng.standard_normal((T, S, 3))
    return form, f, np.ones((T, S)), wi, wo


def test_the_solver_module_is_written_once_under_a_name_that_hashes_its_source(tmp_path, monkeypatch):
    """The loops are copied next to the kernel cache with the kernel's import in place of the stand-in, under a
    name that changes with the template or the kernel's source, so a stale compiled loop is never reused."""
    monkeypatch.setenv("SBRDF_KERNEL_CACHE", str(tmp_path))
    monkeypatch.setattr(engine, "_loaded", {})
    form = _lambert_problem()[0]
    mod = engine.solver(form.kernel)
    files = list(tmp_path.glob("lm_*.py"))
    assert len(files) == 1 and files[0].name.startswith("lm_sbrdf_models_lambert_fit_kernel_")
    text = files[0].read_text()
    assert "from sbrdf_models.lambert import fit_kernel as _source  # KERNEL" in text
    assert "kernel = None  # KERNEL" not in text
    assert engine.solver(form.kernel) is mod  # once a process
    monkeypatch.setattr(engine, "_loaded", {})
    engine.solver(form.kernel)
    assert list(tmp_path.glob("lm_*.py")) == files  # the same name for the same sources


def test_a_kernel_must_be_importable_by_name():
    def local(x, cfg, wi, wo, f, J):
        pass

    with pytest.raises(TypeError, match="module-level function"):
        engine.solver(local)


def test_a_second_process_loads_the_compiled_loop_from_the_cache(tmp_path):
    """Compile once: a fresh process finds the solver another one compiled (numba's on-disk cache) and compiles
    nothing."""
    script = textwrap.dedent("""
        import numpy as np
        from sbrdf_core import engine
        from sbrdf_core.registry import Registry
        form = Registry().create("brdf-model", "lambert", {}).fit_form()
        problem = engine.CompiledProblem(form, np.full((2, 3, 3), 0.2), np.ones((2, 3)),
                                         np.tile([0.0, 0.0, 1.0], (2, 3, 1)), np.tile([0.0, 0.0, 1.0], (2, 3, 1)))
        print(problem.cost(np.full((2, 3), 0.1), np.arange(2)).tolist())
        stats = engine.solver(form.kernel).costs.stats
        print(sum(stats.cache_hits.values()), sum(stats.cache_misses.values()))
    """)
    env = {**os.environ, "SBRDF_KERNEL_CACHE": str(tmp_path)}
    runs = [subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True)
            for _ in range(2)]
    first, second = (r.stdout.split("\n") for r in runs)
    assert first[0] == second[0]
    assert first[1] == "0 1" and second[1] == "1 0"


def test_worker_threads_get_the_main_threads_numbers():
    """Slices of texels run on several threads from the main thread and on one from a worker thread (dask's):
    texels are independent, so the results are the same bits."""
    from sbrdf_lib.lm import fit_model

    model = Registry().create("brdf-model", "ward", {})
    rng = np.random.default_rng(4)
    T, S = 512, 200
    wi = rng.normal(size=(T, S, 3))
    wi[..., 2] = np.abs(wi[..., 2])
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo = wi[:, ::-1].copy()
    f = model.eval(model.random_guess(rng, T), wi, wo) * (1 + 0.02 * rng.standard_normal((T, S, 3)))
    valid = np.ones((T, S), bool)
    main = fit_model(model, f, valid, wi, wo)
    out = {}
    worker = threading.Thread(target=lambda: out.setdefault("r", fit_model(model, f, valid, wi, wo)))
    worker.start()
    worker.join()
    assert engine.threads() >= 1
    for k in main[0]:
        np.testing.assert_array_equal(out["r"][0][k], main[0][k])
    np.testing.assert_array_equal(out["r"][2], main[2])


def test_a_lobe_more_never_fits_worse(registry):
    """``lm`` with 2 Lafortune lobes is never worse than with 1 on its own training samples, per texel, in the
    plain RMS users read (the objective is weighted), under the Fit node's limits and as the node leaves it (the
    energy bound held), on lobes that rise toward grazing as real ones do."""
    from sbrdf_core.constraints import angular_resolution, enforce, sample_support
    from sbrdf_core.nodes.fit import FitOptions
    from sbrdf_lib.lm import fit_model
    from sbrdf_models.lafortune import LafortuneModel

    rng = np.random.default_rng(7)
    T, S = 96, 120
    th = np.arccos(rng.uniform(np.cos(np.radians(80)), 1, (2, T, S)))
    ph = rng.uniform(0, 2 * np.pi, (2, T, S))
    d = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    wi, wo = d[0], d[1]
    truth = LafortuneModel(lobes=2)
    p = truth.defaults(T)
    n1 = rng.uniform(10, 150, (T, 1))
    p.update(rho_d=rng.uniform(0.01, 0.3, (T, 3)), rho_s_1=rng.uniform(0.2, 0.6, (T, 3)) * (n1 + 2) / 6.28,
             c_xy_1=-rng.uniform(1.0, 1.02, (T, 1)), exponent_1=n1, rho_s_2=rng.uniform(0.05, 0.1, (T, 3)),
             c_xy_2=np.full((T, 1), -1.1), exponent_2=rng.uniform(3, 6, (T, 1)))
    f = truth.eval(p, wi, wo)
    f = f + 0.01 * np.sqrt(np.abs(f)) * rng.standard_normal(f.shape)
    valid = np.ones((T, S), bool)
    limits = FitOptions().limits(sample_support(f, valid), angular_resolution(wi, wo, valid))
    bounded, moved = {}, {}
    for lobes in (1, 2):
        model = LafortuneModel(lobes=lobes)
        params, _, _ = fit_model(model, f, valid, wi, wo, weighting="shot-noise", limits=limits)
        # as the Fit node leaves it: every bound held (the energy bound scales magnitudes afterwards)
        held, moved[lobes] = enforce(model, params, limits)
        bounded[lobes] = np.sqrt(((model.eval(held, wi, wo) - f) ** 2).sum(axis=(1, 2)) / (3 * S))
    assert moved[1].any()  # the energy bound is in play
    assert not moved[2].any()  # lm held it already, to compare the two as the node leaves them
    assert (bounded[2] <= bounded[1] * (1 + 1e-6)).all()
    assert bounded[2].mean() < bounded[1].mean()


def test_small_batches_are_left_to_numpy():
    form, f, valid, wi, wo = _lambert_problem(T=2, S=3)
    params = form.unpack(np.full((2, 3), 0.2))
    assert engine.evaluate(form, params, wi, wo) is None


@pytest.mark.parametrize("name,cfg", [("cook-torrance", {"distribution": "ggx"}), ("ward", {"anisotropic": True}),
                                      ("ggx-anisotropic", {}), ("phong", {}), ("lambert", {})])
def test_magnitudes_solved_by_the_kernel_are_numpys(name, cfg):
    """``refine_linear`` by the fit kernel (``engine.solve_linear``, what the fitters' starts use) gives the NumPy
    solve of the same system, clipped to the same bounds, on noisy data with invalid samples."""
    model = Registry().create("brdf-model", name, cfg)
    plain = type("NoKernel", (type(model),), {"fit_kernel": None})(**cfg)  # the NumPy path, the oracle
    assert plain.fit_form().kernel is None
    rng = np.random.default_rng(5)
    T, S = 48, 90
    truth = model.random_guess(rng, T)
    theta_i, theta_o = rng.uniform(0, 1.3, (2, T, S))
    phi_i, phi_o = rng.uniform(0, 2 * np.pi, (2, T, S))
    d = lambda t, p: np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)  # noqa: E731
    wi, wo = d(theta_i, phi_i), d(theta_o, phi_o)
    f_r = model.eval(truth, wi, wo) * rng.uniform(0.8, 1.2, (T, S, 3))
    valid = rng.random((T, S)) > 0.2
    start = model.random_guess(np.random.default_rng(6), T)  # other shapes: the magnitudes do the fitting
    got, want = model.refine_linear(start, f_r, valid, wi, wo), plain.refine_linear(start, f_r, valid, wi, wo)
    for p in model.parameters:
        np.testing.assert_allclose(got[p.name], want[p.name], rtol=1e-6, atol=1e-9, err_msg=p.name)
    assert any(not np.allclose(got[p.name], start[p.name]) for p in model.parameters if p.magnitude)


@pytest.mark.parametrize("cfg", [{"lobes": 2}, {"lobes": 1, "anisotropic": True, "beta": True}])
def test_lafortune_magnitudes_solved_by_the_kernel_are_numpys(cfg):
    """Lafortune's ``refine_linear`` (ρ_s of every lobe, ρ_d and the shapes held) by the fit kernel gives its NumPy
    reference, ``solve_magnitudes``."""
    from sbrdf_models.lafortune_fit import solve_magnitudes

    form = Registry().create("brdf-model", "lafortune", cfg).fit_form()
    rng = np.random.default_rng(7)
    T, S = 40, 80
    theta_i, theta_o = rng.uniform(0, 1.3, (2, T, S))
    phi_i, phi_o = rng.uniform(0, 2 * np.pi, (2, T, S))
    d = lambda t, p: np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)  # noqa: E731
    wi, wo = d(theta_i, phi_i), d(theta_o, phi_o)
    f_r = form.eval(form.random_guess(rng, T), wi, wo) * rng.uniform(0.8, 1.2, (T, S, 3))
    valid = rng.random((T, S)) > 0.2
    start = form.random_guess(np.random.default_rng(8), T)
    got = form.refine_linear(start, f_r, valid, wi, wo)
    want = solve_magnitudes(form, start, f_r, valid, wi, wo)
    for name, value in want.items():
        np.testing.assert_allclose(got[name], value, rtol=1e-6, atol=1e-9, err_msg=name)


@pytest.mark.parametrize("name,cfg", [("ggx-anisotropic", {}), ("cook-torrance", {"distribution": "beckmann"}),
                                      ("lafortune", {"lobes": 2})])
def test_albedo_by_the_kernel_is_the_quadrature_of_eval(name, cfg):
    """The energy check's quadrature summed by the fit kernel (``engine.integrate``, what ``directional_albedo``
    uses) equals the same grid of ``model.eval`` values, weighted and summed."""
    from sbrdf_core.brdf_checks import directional_albedo, quadrature

    model = Registry().create("brdf-model", name, cfg)
    params = model.random_guess(np.random.default_rng(3), 16)
    wi = np.array([np.sin(1.2), 0.0, np.cos(1.2)])
    dirs, weights = quadrature(16, 32)
    want = np.einsum("tsc,s->tc", model.eval(params, np.broadcast_to(wi, (16, len(dirs), 3)),
                                             np.broadcast_to(dirs, (16, len(dirs), 3))), weights)
    assert engine.integrate(model, params, np.broadcast_to(wi, (16, 3)), dirs, weights) is not None
    np.testing.assert_allclose(directional_albedo(model, params, wi, n_theta=16, n_phi=32), want, rtol=1e-9,
                               atol=1e-12)
