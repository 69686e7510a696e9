"""lm-gl's compute shader: one invocation per texel runs its Levenberg–Marquardt fit, a chunk of iterations a dispatch.

Each invocation reads its texel's samples from a shader storage buffer,
accumulates the normal equations ``JᵀJ`` (packed lower triangle) and ``Jᵀr``
from the model's ``brdf_fit_gradient`` (value and ∂f/∂x in the fit form), and
solves the damped system by Cholesky in float32.  The system is solved with
Jacobi scaling (Â = D^-½ A D^-½, unit diagonal): that is Marquardt's
``A + λ diag(A)`` exactly, and it keeps float32 pivots near 1 where a raw
``JᵀJ`` spans many decades (ρ vs log n columns).  A failed factorisation
(a pivot at round-off) is a rejected step: λ grows, as for a worse cost.

Acceptance, λ updates and the stopping tests are those of
:func:`sbrdf_lib.lm.levenberg_marquardt`; only the "negligible step" test is
relative to float32's resolution (1e-6) rather than float64's.

Buffers (float32):

- samples ``[S][T][10]``: ω_i, ω_o, f_r RGB, weight (0 = skip; weights
  already carry the texel's residual scale);
- state ``[T][K + 4]``: x (in: start, out: result), cost, status (in: 0 =
  fit, 1 = leave alone; out: 0 = still running, 1 = converged, 2 = stopped at
  the iteration cap in stepwise mode), exact-fit threshold, iterations;
- work ``[T][NA + 2K + 2]``: JᵀJ, Jᵀr, trial point (stepwise), λ, ok (stepwise), kept between dispatches;
- limits ``[T][3]``: peak, resolution, peak_cosine (−1: off), read where
  ``u_constrain`` is set (:mod:`sbrdf_core.constraints_glsl`).

``u_mode`` 1 starts every fit (projects the start, keeps its normal
equations and λ in the work buffer); mode 0 then runs up to ``u_chunk``
iterations per dispatch from there, as many dispatches as ``iterations``
needs.  Chunks, not one dispatch per fit: llvmpipe ends every loop of an
invocation once 65 535 loop iterations have run in it in all
(``LP_MAX_TGSI_LOOP_ITERATIONS``), which ~50 LM iterations over 400 samples
reach, silently truncating the sample sums; a GPU driver's watchdog also
prefers short dispatches (:func:`chunk`).  With ``u_constrain`` the start
and every trial point are projected onto the texel's plausibility limits by
the model's ``glsl_fit_constrain``, as :func:`sbrdf_lib.lm.levenberg_marquardt`
projects them.  For a model without that member the projection is the CPU's
(the model's numpy ``constrain``) and the fit is stepwise: mode 1 starts it,
then per iteration mode 2 proposes a trial point, the CPU projects it, and
mode 3 evaluates and accepts or rejects it: :func:`sbrdf_lib.lm.levenberg_marquardt`
step for step.
"""

from __future__ import annotations

from sbrdf_core.constraints_glsl import LIMITS_STRIDE

#: Floats per sample: ω_i (3), ω_o (3), f_r (3), weight.
SAMPLE = 10
#: Invocations per workgroup.
GROUP = 64


def state_stride(K: int) -> int:
    return K + 4


def work_stride(K: int) -> int:
    """Floats per texel a stepwise fit keeps between dispatches: JᵀJ (packed), Jᵀr, the trial point, λ, ok."""
    return K * (K + 1) // 2 + 2 * K + 2


#: Loop iterations one dispatch's invocation may run (llvmpipe stops every loop after 65 535 in all), with margin.
LOOP_BUDGET = 40000


def chunk(samples: int, K: int, constrained: bool) -> int:
    """LM iterations per dispatch: each costs about ``samples`` + K³ loop iterations (sample sums, Cholesky),
    plus the projection's loops (a bisection over mirror pairs: ~2000) and the peak bound's gradient (48 mirror
    pairs)."""
    return max(1, LOOP_BUDGET // (samples + K**3 + 64 * K + (2000 + 48 * K if constrained else 0)))


def source(gradient_glsl: str, K: int, constrain_glsl: str | None = None, along: bool = False) -> str:
    """The compute shader for a model whose ``brdf_fit_gradient`` is ``gradient_glsl``, ``K`` fit parameters;
    ``constrain_glsl``, the model's ``glsl_fit_constrain()``, projects trial points where ``u_constrain`` is set.
    ``along``: the projection widens the roughness to the peak bound (the fit form's ``peak_widths``), and
    while that bound is active steps are taken along it, as the CPU engine's ``along_bound`` does."""
    NA = K * (K + 1) // 2
    stride, work = state_stride(K), work_stride(K)
    if constrain_glsl is None:  # never called (u_constrain stays 0): the CPU projects, stepwise
        constrain_glsl = (f"void brdf_fit_constrain(inout float x[{K}], float peak, float resolution, "
                          "float peak_cosine, float growth, float max_theta) {}")
    return f"""#version 430
layout(local_size_x = {GROUP}) in;
layout(std430, binding = 0) readonly buffer Samples {{ float smp[]; }};
layout(std430, binding = 1) buffer State {{ float st[]; }};
layout(std430, binding = 2) buffer Work {{ float wk[]; }};
layout(std430, binding = 3) readonly buffer Limits {{ float lim[]; }};
uniform int u_mode;
uniform int u_constrain;
uniform float u_growth;
uniform float u_max_theta;
uniform int u_texels;
uniform int u_samples;
uniform int u_iterations;
uniform int u_chunk;
uniform float u_tolerance;
uniform float u_damping;
uniform float u_lo[{K}];
uniform float u_hi[{K}];
uniform float u_free[{K}];
uniform float u_max_step[{K}];
const int K = {K};
const int NA = {NA};
const bool ALONG = {"true" if along else "false"};

{gradient_glsl}

{constrain_glsl}

// The trial point onto the texel's plausibility limits, as the model's numpy constrain (fit form) does.
void project(int t, inout float x[K]) {{
    if (u_constrain == 0) return;
    int o = t * {LIMITS_STRIDE};
    brdf_fit_constrain(x, lim[o], lim[o + 1], lim[o + 2], u_growth, u_max_theta);
}}

float normal_equations(int t, float x[K], out float A[NA], out float g[K]) {{
    for (int i = 0; i < NA; ++i) A[i] = 0.0;
    for (int i = 0; i < K; ++i) g[i] = 0.0;
    float cost = 0.0;
    for (int s = 0; s < u_samples; ++s) {{
        int o = (s * u_texels + t) * {SAMPLE};
        float w = smp[o + 9];
        if (w == 0.0) continue;
        vec3 wi = vec3(smp[o], smp[o + 1], smp[o + 2]);
        vec3 wo = vec3(smp[o + 3], smp[o + 4], smp[o + 5]);
        vec3 J[K];
        vec3 r = (brdf_fit_gradient(wi, wo, x, J) - vec3(smp[o + 6], smp[o + 7], smp[o + 8])) * w;
        cost += dot(r, r);
        for (int i = 0; i < K; ++i) {{
            J[i] *= w * u_free[i];
            g[i] += dot(J[i], r);
            int row = i * (i + 1) / 2;
            for (int j = 0; j <= i; ++j) A[row + j] += dot(J[i], J[j]);
        }}
    }}
    return cost;
}}

bool finite(float v) {{ return !isnan(v) && !isinf(v); }}

// The damped step from x over the parameters fr marks free: Cholesky of D^-1/2 A D^-1/2 + lam I (a frozen
// parameter's row and column replaced by the identity's); xn the step clamped to the box, xr unclamped; false when a
// pivot is at round-off.
// The peak bound's log gradient at x where the bound is active (the peak within 0.1 % below it), as the CPU
// engine's mirror_peak: f_r (times cos^2 for peak_cosine) over the mirror pairs, the gradient where it is largest.
bool peak_gradient(int t, float x[K], out float c[K]) {{
    for (int k = 0; k < K; ++k) c[k] = 0.0;
    if (!ALONG || u_constrain == 0) return false;
    int o = t * {LIMITS_STRIDE};
    bool cosine = lim[o + 2] >= 0.0;
    float bound = cosine ? lim[o + 2] : lim[o];
    if (!(bound > 0.0)) return false;
    float best = -1.0;
    for (int i = 0; i < 24; ++i) {{
        float th = u_max_theta * float(i) / 23.0, st = sin(th), ct = cos(th);
        float w = cosine ? ct * ct : 1.0;
        for (int a = 0; a < 2; ++a) {{
            vec3 d = a == 0 ? vec3(st, 0.0, ct) : vec3(0.0, st, ct);
            vec3 J[K];
            vec3 f = brdf_fit_gradient(d, vec3(-d.xy, d.z), x, J) * w;
            for (int ch = 0; ch < 3; ++ch) {{
                if (f[ch] > best) {{
                    best = f[ch];
                    for (int k = 0; k < K; ++k) c[k] = J[k][ch] * w;
                }}
            }}
        }}
    }}
    if (!(best > 0.0 && best >= bound * exp(-1e-3) && finite(best))) return false;
    for (int k = 0; k < K; ++k) c[k] /= best;
    return true;
}}

// Solve (L L^T) y = b with the Cholesky factor propose builds (packed lower triangle).
void cholesky_solve(float M[NA], float b[K], out float y[K]) {{
    for (int i = 0; i < K; ++i) {{
        int ri = i * (i + 1) / 2;
        float v = b[i];
        for (int k = 0; k < i; ++k) v -= M[ri + k] * y[k];
        y[i] = v / M[ri + i];
    }}
    for (int i = K - 1; i >= 0; --i) {{
        float v = y[i];
        for (int k = i + 1; k < K; ++k) v -= M[k * (k + 1) / 2 + i] * y[k];
        y[i] = v / M[i * (i + 1) / 2 + i];
    }}
}}

bool propose(float A[NA], float g[K], float x[K], float lam, float fr[K], bool along, float c[K], out float xn[K],
             out float xr[K]) {{
    float M[NA], d[K], y[K];
    for (int k = 0; k < K; ++k) {{
        xn[k] = x[k];
        xr[k] = x[k];
        d[k] = fr[k] > 0.0 ? sqrt(max(A[k * (k + 1) / 2 + k], 1e-12)) : 1.0;
    }}
    for (int i = 0; i < K; ++i) {{
        int ri = i * (i + 1) / 2;
        for (int j = 0; j <= i; ++j) {{
            int rj = j * (j + 1) / 2;
            float a = fr[i] > 0.0 && fr[j] > 0.0 ? A[ri + j] : (i == j ? 1.0 : 0.0);
            float v = a / (d[i] * d[j]) + (i == j ? lam : 0.0);
            for (int k = 0; k < j; ++k) v -= M[ri + k] * M[rj + k];
            if (i == j) {{
                if (!(v > 1e-7 * (1.0 + lam))) return false;
                M[ri + i] = sqrt(v);
            }} else {{
                M[ri + j] = v / M[rj + j];
            }}
        }}
    }}
    float b[K];
    for (int k = 0; k < K; ++k) b[k] = fr[k] > 0.0 ? -g[k] / d[k] : 0.0;
    cholesky_solve(M, b, y);
    for (int k = 0; k < K; ++k) {{
        float step = fr[k] > 0.0 ? y[k] / d[k] : 0.0;
        y[k] = finite(step) ? step : 0.0;
    }}
    if (along) {{  // the step on the plane c . step = 0 where it would raise the active peak bound
        float z[K];
        for (int k = 0; k < K; ++k) b[k] = fr[k] > 0.0 ? c[k] / d[k] : 0.0;
        cholesky_solve(M, b, z);
        float cs = 0.0, cz = 0.0;
        for (int k = 0; k < K; ++k) {{
            z[k] = fr[k] > 0.0 ? z[k] / d[k] : 0.0;
            cs += (fr[k] > 0.0 ? c[k] : 0.0) * y[k];
            cz += (fr[k] > 0.0 ? c[k] : 0.0) * z[k];
        }}
        if (cs > 0.0 && cz > 0.0 && finite(cz)) {{
            for (int k = 0; k < K; ++k) y[k] -= z[k] * cs / cz;
        }}
    }}
    float scale = 1.0;  // the step shortened along its direction to u_max_step (sbrdf_lib.lm.limit_step)
    for (int k = 0; k < K; ++k) {{
        if (abs(y[k]) > u_max_step[k]) scale = min(scale, u_max_step[k] / abs(y[k]));
    }}
    for (int k = 0; k < K; ++k) {{
        xr[k] = x[k] + scale * y[k];
        xn[k] = clamp(xr[k], u_lo[k], u_hi[k]);
    }}
    return true;
}}

// The projected trial point of lm's active set (sbrdf_lib.lm._active_set_step): where the projection held a
// parameter where it was (the step pointing out of its bound), the others' step is solved again with it frozen.
bool propose_projected(int t, float A[NA], float g[K], float x[K], float lam, out float xn[K]) {{
    float fr[K], xr[K], c[K];
    for (int k = 0; k < K; ++k) fr[k] = u_free[k];
    bool along = peak_gradient(t, x, c);
    bool ok = propose(A, g, x, lam, fr, along, c, xn, xr);
    if (!ok) return false;
    project(t, xn);
    bool pinned = false;
    for (int k = 0; k < K; ++k) {{
        float scale = 1e-6 * max(abs(x[k]), 1.0);
        if (fr[k] > 0.0 && abs(xn[k] - xr[k]) > scale && abs(xn[k] - x[k]) <= scale) {{ fr[k] = 0.0; pinned = true; }}
    }}
    if (!pinned) return true;
    float xs[K];
    if (!propose(A, g, x, lam, fr, along, c, xs, xr)) return true;  // keep the first trial point
    project(t, xs);
    xn = xs;
    return true;
}}

// Accept or reject the trial xn (cost cn, normal equations An, gn); false when the texel is done.
bool settle(bool ok, float xn[K], float cn, float An[NA], float gn[K], float exact, inout float x[K],
            inout float A[NA], inout float g[K], inout float cost, inout float lam) {{
    float biggest = 0.0, largest_x = 0.0;
    for (int k = 0; k < K; ++k) {{
        biggest = max(biggest, abs(xn[k] - x[k]));
        largest_x = max(largest_x, abs(x[k]));
    }}
    bool better = ok && finite(cn) && cn < cost;
    float gain = better ? (cost - cn) / max(cost, 1e-30) : 0.0;
    if (better) {{ x = xn; A = An; g = gn; cost = cn; }}
    lam = better ? max(lam / 3.0, 1e-12) : lam * 4.0;
    bool negligible = ok && biggest <= 1e-6 * max(largest_x, 1e-12);
    return !((better && gain < u_tolerance) || (!better && negligible) || lam > 1e10 || cost <= exact);
}}

void main() {{
    int t = int(gl_GlobalInvocationID.x);
    if (t >= u_texels) return;
    int so = t * {stride}, wb = t * {work};
    float x[K], xn[K], A[NA], g[K], An[NA], gn[K];
    for (int k = 0; k < K; ++k) x[k] = st[so + k];
    float exact = st[so + K + 2];
    if (u_mode == 1) {{  // the start: projected, its normal equations kept for the iterations
        project(t, x);
        float cost = normal_equations(t, x, A, g);
        bool running = st[so + K + 1] == 0.0 && cost > 0.0 && finite(cost);
        for (int k = 0; k < K; ++k) st[so + k] = x[k];
        st[so + K] = cost;
        st[so + K + 1] = running ? 0.0 : 1.0;
        st[so + K + 3] = 0.0;
        for (int i = 0; i < NA; ++i) wk[wb + i] = A[i];
        for (int k = 0; k < K; ++k) wk[wb + NA + k] = g[k];
        wk[wb + NA + 2 * K] = u_damping;
        return;
    }}
    if (st[so + K + 1] != 0.0) return;  // done
    for (int i = 0; i < NA; ++i) A[i] = wk[wb + i];
    for (int k = 0; k < K; ++k) g[k] = wk[wb + NA + k];
    float lam = wk[wb + NA + 2 * K];
    if (u_mode == 0) {{  // up to u_chunk iterations from the kept state, every trial point projected
        float cost = st[so + K];
        int it = int(st[so + K + 3]);
        int stop = min(it + u_chunk, u_iterations);
        bool running = true;
        for (; it < stop && running; ++it) {{
            bool ok = propose_projected(t, A, g, x, lam, xn);
            float cn = ok ? normal_equations(t, xn, An, gn) : cost;
            running = settle(ok, xn, cn, An, gn, exact, x, A, g, cost, lam);
        }}
        for (int k = 0; k < K; ++k) st[so + k] = x[k];
        st[so + K] = cost;
        st[so + K + 1] = running ? 0.0 : 1.0;
        st[so + K + 3] = float(it);
        for (int i = 0; i < NA; ++i) wk[wb + i] = A[i];
        for (int k = 0; k < K; ++k) wk[wb + NA + k] = g[k];
        wk[wb + NA + 2 * K] = lam;
        return;
    }}
    if (u_mode == 2) {{  // propose a trial point, to be projected onto the texel's limits on the CPU
        float fr[K], xr[K], c[K];
        for (int k = 0; k < K; ++k) fr[k] = u_free[k];
        bool ok = propose(A, g, x, lam, fr, false, c, xn, xr);
        for (int k = 0; k < K; ++k) wk[wb + NA + K + k] = xn[k];
        wk[wb + NA + 2 * K + 1] = ok ? 1.0 : 0.0;
        return;
    }}
    // u_mode == 3: evaluate the projected trial point, accept or reject it
    bool ok = wk[wb + NA + 2 * K + 1] > 0.5;
    for (int k = 0; k < K; ++k) xn[k] = wk[wb + NA + K + k];
    float cost = st[so + K];
    float cn = ok ? normal_equations(t, xn, An, gn) : cost;
    bool running = settle(ok, xn, cn, An, gn, exact, x, A, g, cost, lam);
    int it = int(st[so + K + 3]) + 1;
    for (int k = 0; k < K; ++k) st[so + k] = x[k];
    st[so + K] = cost;
    st[so + K + 1] = running && it < u_iterations ? 0.0 : (running ? 2.0 : 1.0);
    st[so + K + 3] = float(it);
    for (int i = 0; i < NA; ++i) wk[wb + i] = A[i];
    for (int k = 0; k < K; ++k) wk[wb + NA + k] = g[k];
    wk[wb + NA + 2 * K] = lam;
}}
"""
