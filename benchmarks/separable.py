"""Separable BRDF approximations: error against terms, texture size and parameterization; SVD against ND in time
and memory (seed 001 §4, §5.2, Figs 5 and 6).

What it measures
----------------
Three BRDFs, each limited to [0, 5] sr⁻¹ as the text does (§6.1) and
decomposed on the fly (``sbrdf_separable.sources.model_function``):

- ``ward``: Ward anisotropic with the text's parameters, k_d = (1, 0, 0)
  (ρ_d = k_d/π), α = (0.21, 0.048), k_s = 0.3;
- ``copper``: Cook–Torrance, Beckmann α = 0.3, F0 = (0.95, 0.64, 0.54), no diffuse;
- ``velvet``: Ashikhmin–Premože velvet, σ = 0.35 (the ``velvet`` model of this package).

Error: §5.2's cosine-weighted RMS of outgoing *luminance* (Rec. 709
weights) over 8000 Monte Carlo pairs uniform over both hemispheres, against
the [0, 5]-limited BRDF, sr⁻¹ (radiance per unit irradiance).

1. Fig 5: SVD with 1..8 terms per parameterization and BRDF (K = 32, the
   text's sampling; 16 with --quick), plus 1-term ND.
2. Fig 6: Ward in Gram–Schmidt, 1-term ND and SVD against texture size
   K = 16..128 (ND; SVD up to 64: at 128 its matrix is 1 GB per channel);
   --quick: 16 and 32.
3. Cost: wall time and peak traced memory (tracemalloc, MB = 10⁶ B) of SVD
   and ND on Ward / Gram–Schmidt at K = 32, 64, 128.  SVD at 128 is not run
   (3.2 GB for the float32 matrix of three channels); its matrix size is
   listed.  ND's cost is linear in the rows of M (one BRDF evaluation per
   grid point per pass): with --quick, ND at 128 runs over 1/64 of the rows
   and its time is scaled by 64 (``nd128_extrapolated=1`` in the last line);
   its peak memory is measured as is (factors + one row block do not depend
   on how many rows are streamed); likewise 1/8 of the rows at K = 64.

The machine line states the load average: other work on the machine skews the times.

``--docs`` rewrites the separable section of docs/accuracy-vs-time.md and its figure.

Last line: ``separable: nd1_rms=... svd1_rms=... svd4_rms=... nd128_s=... nd128_peak_mb=... svd64_s=...``
(Ward, Gram–Schmidt, K = 32 for the errors.)
"""

from __future__ import annotations

import argparse
import datetime
import sys
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
from report import machine, replace_section  # noqa: E402

from sbrdf_separable.error import CLAMP, STUDY, study_brdf  # noqa: E402  (the §5.2 study's BRDFs)

PARAMS = ["gram-schmidt", "rusinkiewicz", "standard", "elevation-azimuth"]


def rms(fn, fac) -> float:
    from sbrdf_separable.error import factors_function, radiance_rms

    return radiance_rms(fn, factors_function(fac))


CPU: dict[tuple[str, int], float] = {}  # (method, K) -> process CPU seconds of the last measurement


def measured(call, key=None):
    """``(result, wall seconds, peak MB)`` of ``call()`` under tracemalloc; CPU seconds go to ``CPU[key]``."""
    tracemalloc.start()
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        out = call()
        CPU[key] = time.process_time() - c0
        return out, time.perf_counter() - t0, tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def terms_study(K, max_terms=8):
    from sbrdf_separable.decompose import nd, parameterization, svd

    out = {}
    for m in STUDY:
        fn = study_brdf(m)
        for p in PARAMS:
            P = parameterization(p)
            S = svd(fn, P, K, terms=max_terms, clamp_max=CLAMP)
            svd_rms = [rms(fn, S.truncated(k)) for k in range(1, max_terms + 1)]
            nd1_rms = rms(fn, nd(fn, P, K, clamp_max=CLAMP))
            out[m, p] = {"svd": svd_rms, "nd1": nd1_rms}
            print(f"  {m:<7} {p:<18} nd1 {nd1_rms:.4f}  svd 1..{max_terms} "
                  + " ".join(f"{e:.4f}" for e in svd_rms), flush=True)
    return out


def size_study(sizes, svd_max):
    from sbrdf_separable.decompose import nd, parameterization, svd

    fn, P = study_brdf("ward"), parameterization("gram-schmidt")
    rows = []
    for K in sizes:
        e_nd = rms(fn, nd(fn, P, K, clamp_max=CLAMP))
        e_svd = rms(fn, svd(fn, P, K, clamp_max=CLAMP)) if K <= svd_max else None
        rows.append((K, e_nd, e_svd))
        print(f"  K={K:<4} nd1 {e_nd:.4f}  svd1 {'-' if e_svd is None else f'{e_svd:.4f}'}", flush=True)
    return rows


def nd_partial(fn, P, K, fraction):
    """ND (1 term, default passes) over the first ``fraction`` of the rows: cost per row is what ND's time is."""
    from sbrdf_separable.decompose import GridSampler, _nd_terms

    s = GridSampler(fn, P, K, CLAMP)
    stop = max(1, int(s.n * fraction))

    def blocks():
        for r0, r1, f, valid in s.blocks():
            if r0 >= stop:
                return
            yield r0, r1, f, valid

    return _nd_terms(blocks, s.n, K, 1, 2.0)


def cost_study(sizes, quick):
    from sbrdf_separable.decompose import matrix_mb, nd, parameterization, svd

    fn, P = study_brdf("ward"), parameterization("gram-schmidt")
    rows = []
    for K in sizes:
        part = {64: 8, 128: 64}.get(K, 1) if quick else 1
        if part > 1:
            _, s, peak = measured(lambda: nd_partial(fn, P, K, 1 / part), ("nd", K))
            CPU["nd", K] *= part
            nd_row = (s * part, peak, True)
        else:
            _, s, peak = measured(lambda: nd(fn, P, K, clamp_max=CLAMP), ("nd", K))
            nd_row = (s, peak, False)
        if K <= 64:
            _, ss, speak = measured(lambda: svd(fn, P, K, clamp_max=CLAMP), ("svd", K))
            svd_row = (ss, speak)
        else:
            svd_row = (None, None)
        rows.append((K, *nd_row, *svd_row, 3 * matrix_mb(K)))
        print(f"  K={K:<4} nd {nd_row[0]:7.1f} s {nd_row[1]:8.1f} MB{' (extrapolated time)' if nd_row[2] else ''}   "
              f"svd {'-' if svd_row[0] is None else f'{svd_row[0]:7.1f} s {svd_row[1]:8.1f} MB'}   "
              f"matrix {3 * matrix_mb(K):.0f} MB", flush=True)
    return rows


def write_docs(terms, K_terms, sizes, costs, line, quick):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    date = datetime.date.today().isoformat()
    docs = ROOT / "docs"
    (docs / "img").mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    for ax, m in zip(axes, STUDY):
        for p in PARAMS:
            e = terms[m, p]["svd"]
            ax.plot(range(1, len(e) + 1), e, "o-", ms=3, label=p)
        ax.set_title(f"{m}: SVD, K = {K_terms}")
        ax.set_xlabel("terms")
        ax.set_ylabel("cos-weighted RMS luminance (sr⁻¹)")
        ax.set_ylim(bottom=0)
    axes[0].legend(fontsize=7)
    ax = axes[3]
    ax.plot([r[0] for r in sizes], [r[1] for r in sizes], "o-", label="ND, 1 term")
    sv = [r for r in sizes if r[2] is not None]
    ax.plot([r[0] for r in sv], [r[2] for r in sv], "s-", label="SVD, 1 term")
    ax.set_xscale("log", base=2)
    ax.set_title("ward, gram-schmidt: texture size")
    ax.set_xlabel("K (K x K texels per factor)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=7)
    fig.suptitle(f"benchmarks/separable.py{' --quick' if quick else ''}: {machine()}, {date}", fontsize=8)
    fig.tight_layout()
    fig.savefig(docs / "img" / "separable-error.png", dpi=110)

    def f(v, fmt="{:.4f}"):
        return "–" if v is None else fmt.format(v)

    head = "| BRDF | parameterization | ND 1 | SVD 1 | SVD 2 | SVD 4 | SVD 8 |\n|---|---|---|---|---|---|---|\n"
    table = head + "".join(
        f"| {m} | {p} | {f(terms[m, p]['nd1'])} | " + " | ".join(f(terms[m, p]['svd'][k - 1]) for k in (1, 2, 4, 8))
        + " |\n" for m in STUDY for p in PARAMS)
    size_table = "| K | ND 1 term | SVD 1 term |\n|---|---|---|\n" + "".join(
        f"| {K} | {f(a)} | {f(b)} |\n" for K, a, b in sizes)
    cost_table = ("| K | ND wall s | ND CPU s | ND peak MB | SVD wall s | SVD CPU s | SVD peak MB | matrix MB (3 × float32) |\n"
                  "|---|---|---|---|---|---|---|---|\n"
                  + "".join(f"| {K} | {f(ns, '{:.1f}')}{'*' if ext else ''} | {f(CPU.get(('nd', K)), '{:.1f}')} | "
                            f"{f(npk, '{:.1f}')} | {f(ss, '{:.1f}')} | {f(CPU.get(('svd', K)), '{:.1f}')} | "
                            f"{f(spk, '{:.0f}')} | {mb:.0f} |\n" for K, ns, npk, ext, ss, spk, mb in costs))
    section = "\n".join([
        "<!-- separable:begin (generated by benchmarks/separable.py --docs; do not edit by hand) -->",
        "## Separable BRDFs (Kautz & McCool): terms, texture size, SVD against ND",
        "",
        f"Machine: {machine()}. Date: {date}."
        + (" Run with `--quick`." if quick else ""),
        "",
        "Error: cosine-weighted RMS of outgoing luminance over 8000 uniform pairs (§5.2), sr⁻¹, against the BRDF "
        "limited to [0, 5] (the range the decomposition is given, §6.1). Ward: the text's parameters; copper: "
        "Cook–Torrance Beckmann α = 0.3; velvet: Ashikhmin–Premože σ = 0.35. See [separable.md](separable.md).",
        "",
        "![error against terms and texture size](img/separable-error.png)",
        "",
        f"Fig 5: error against SVD terms, K = {K_terms}:",
        "",
        table,
        "Fig 6: Ward, Gram–Schmidt, against factor size K:",
        "",
        size_table,
        "Cost (Ward, Gram–Schmidt, one term; ND streams, SVD holds the K² × K² matrix per channel; SVD at 128 "
        "not run)" + (" — * ND time over 1/8 (K = 64) or 1/64 (K = 128) of the rows, scaled up" if quick else "") + ":",
        "",
        cost_table,
        "```",
        line,
        "```",
        "<!-- separable:end -->",
        "",
    ])
    replace_section("separable", section)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, about a minute")
    ap.add_argument("--docs", action="store_true", help="rewrite the separable section of docs/accuracy-vs-time.md")
    args = ap.parse_args(argv)
    K_terms = 16 if args.quick else 32
    print(f"# {machine()}", flush=True)
    print(f"1. error against SVD terms (K = {K_terms})", flush=True)
    terms = terms_study(K_terms)
    print("2. error against texture size (ward, gram-schmidt)", flush=True)
    sizes = size_study([16, 32] if args.quick else [16, 32, 64, 128], 32 if args.quick else 64)
    print("3. time and peak memory (ward, gram-schmidt)", flush=True)
    costs = cost_study([32, 64, 128], args.quick)
    # the headline errors at K = 32 (the text's sampling)
    from sbrdf_separable.decompose import nd, parameterization, svd

    fn, P = study_brdf("ward"), parameterization("gram-schmidt")
    S = svd(fn, P, 32, terms=4, clamp_max=CLAMP)
    nd1, svd1, svd4 = rms(fn, nd(fn, P, 32, clamp_max=CLAMP)), rms(fn, S.truncated(1)), rms(fn, S)
    c128 = next(r for r in costs if r[0] == 128)
    c64 = next(r for r in costs if r[0] == 64)
    line = (f"separable: nd1_rms={nd1:.5f} svd1_rms={svd1:.5f} svd4_rms={svd4:.5f} nd128_s={c128[1]:.1f} "
            f"nd128_peak_mb={c128[2]:.1f} svd64_s={c64[4]:.1f}" + (" nd128_extrapolated=1" if c128[3] else ""))
    if args.docs:
        write_docs(terms, K_terms, sizes, costs, line, args.quick)
    print(line)


if __name__ == "__main__":
    main()
