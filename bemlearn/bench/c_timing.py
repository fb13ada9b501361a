"""Time the exported C predictor in a C loop, and the arithmetic floor of one query.

A small C harness (compiled at bench time with the system ``cc``) calls ``<prefix>_mean``,
``<prefix>_forward`` (mean and calibrated band) and ``<prefix>_forward_latent`` (mean and latent
std) on ``n_inputs`` different in-range queries in turn, ``calls`` calls per
timed batch, and reports the median over batches of the per-call time (``clock_gettime``,
monotonic).  The same harness measures the *arithmetic floor* of one query:

    bem_mean:    M exp calls + M (n + 1) multiply-adds      (n = 3m exponent terms and w_j k_j)
    bem_forward_latent: the above + M(M + 1)/2 (exact, triangular solve), M(M + 1)/2 + M²
                 (factored sgpr/svgp) or M² (unfactored sgpr/svgp) multiply-adds
    bem_forward: the above + n M for the band's gradient term (when the BEM inputs carry input noise)
                 + K M for its estimator term (K = ``<PREFIX>_N_ESTIMATORS``)

timed as ⌈M/32⌉ blocks of 32 values of the export's own exp block, summed (float64:
branch-free, vectorized by the compiler; float32: libm ``expf``) on in-range arguments (e ∈ [−20, 0]) and that many
independent multiply-adds in a loop the compiler may vectorize; the floor is their sum.
M calls of libm's scalar ``exp`` are timed too, for comparison.  The harness includes
the generated ``.c`` file so it can call the export's static exp block.
"""

from __future__ import annotations

import re
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bemlearn.errors import EnvironmentProblem
from bemlearn.export.c_build import find_cc

__all__ = ["CTiming", "time_c_predictor", "HARNESS", "FLAG_SETS"]

#: Build flags timed: the portable default and a native build.
FLAG_SETS = {"-O2": ("-std=c99", "-O2"), "-O3 -march=native": ("-std=c99", "-O3", "-march=native")}

HARNESS = r"""#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "@P@_predictor.c"   /* the export itself, for its static exp block */

static double now_ns(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return 1e9 * t.tv_sec + t.tv_nsec; }
static int cmp(const void *a, const void *b) { double x = *(const double *)a, y = *(const double *)b; return (x > y) - (x < y); }
static double median(double *v, int n) { qsort(v, n, sizeof *v, cmp); return v[n / 2]; }

int main(int argc, char **argv)
{
    int n_in = atoi(argv[1]), calls = atoi(argv[2]), batches = atoi(argv[3]), i, b, c;
    int n = @U@_N_INPUTS, M = @U@_N_SUPPORT;
    long fmas_fwd = atol(argv[4]);
    @P@_real *x = malloc(sizeof *x * n * n_in), m, s;
    double *t = malloc(sizeof *t * batches), t0, sink = 0;
    double *e = malloc(sizeof *e * M), *a = malloc(sizeof *a * 4096), *w = malloc(sizeof *w * 4096);
    for (i = 0; i < n * n_in; ++i) if (scanf("%lf", &t0) == 1) x[i] = (@P@_real)t0;
    int mpad = (M + @U@_BLOCK - 1) / @U@_BLOCK * @U@_BLOCK;
    @P@_real *ep = malloc(sizeof *ep * mpad);
    for (i = 0; i < M; ++i) e[i] = -20.0 * (i % 97) / 96.0;
    for (i = 0; i < mpad; ++i) ep[i] = (@P@_real)e[i % M];
    for (i = 0; i < 4096; ++i) { a[i] = 1e-3 * (i % 13); w[i] = 1.0 - 1e-4 * (i % 7); }
    for (c = 0; c < calls * 10; ++c) sink += @P@_mean(x + n * (c % n_in));
    for (b = 0; b < batches; ++b) {
        t0 = now_ns();
        for (c = 0; c < calls; ++c) sink += @P@_mean(x + n * (c % n_in));
        t[b] = (now_ns() - t0) / calls;
    }
    printf("mean_ns %.3f\n", median(t, batches));
    for (b = 0; b < batches; ++b) {
        t0 = now_ns();
        for (c = 0; c < calls; ++c) { @P@_forward(x + n * (c % n_in), &m, &s); sink += m + s; }
        t[b] = (now_ns() - t0) / calls;
    }
    printf("forward_ns %.3f\n", median(t, batches));
    for (b = 0; b < batches; ++b) {
        t0 = now_ns();
        for (c = 0; c < calls; ++c) { @P@_forward_latent(x + n * (c % n_in), &m, &s); sink += m + s; }
        t[b] = (now_ns() - t0) / calls;
    }
    printf("forward_latent_ns %.3f\n", median(t, batches));
    for (b = 0; b < batches; ++b) {          /* M exp calls */
        double acc = 0;
        t0 = now_ns();
        for (c = 0; c < calls; ++c) for (i = 0; i < M; ++i) acc += exp(e[i] + 1e-9 * c);
        t[b] = (now_ns() - t0) / calls;
        sink += acc;
    }
    printf("exp_ns_per_query %.3f\n", median(t, batches));
    for (b = 0; b < batches; ++b) {          /* the export's own exp: ceil(M / BLOCK) blocks, summed */
        double out[@U@_BLOCK], acc = 0;
        int l;
        t0 = now_ns();
        for (c = 0; c < calls; ++c) {
            ep[c % mpad] -= 1e-12;
            for (i = 0; i < mpad; i += @U@_BLOCK) {
                @P@_exp_block(ep + i, out);
                for (l = 0; l < @U@_BLOCK; ++l) acc += out[l];
            }
        }
        t[b] = (now_ns() - t0) / calls;
        sink += acc;
    }
    printf("expblock_ns_per_query %.3f\n", median(t, batches));
    for (b = 0; b < batches; ++b) {          /* 10^6 independent multiply-adds, 4096-long vectorizable rows */
        long done = 0;
        t0 = now_ns();
        while (done < 1000000) {
            for (i = 0; i < 4096; ++i) a[i] = a[i] * w[i] + 1e-9;
            done += 4096;
        }
        t[b] = (now_ns() - t0) / done;
        sink += a[b % 4096];
    }
    printf("fma_ns %.6f\n", median(t, batches));
    printf("sink %g %ld\n", sink, fmas_fwd);
    return 0;
}
"""


@dataclass(frozen=True)
class CTiming:
    """Per-query C times, ns, for one build.

    Attributes:
        flags: the build flags.
        mean_ns, forward_ns: median per call of ``<prefix>_mean`` / ``<prefix>_forward`` (band).
        exp_ns: M calls of libm's ``exp``; exp_block_ns: M values of the export's own
            (vectorizable, float64) exp block; fma_ns: one multiply-add (throughput).
        n_exp, n_fma_mean, n_fma_forward: operation counts of one query (forward: with the band).
        forward_latent_ns: median per call of ``<prefix>_forward_latent`` (NaN if not timed).
        n_fma_band: multiply-adds of the band's gradient and estimator terms (0 without either), part of
            n_fma_forward.
    """

    flags: str
    mean_ns: float
    forward_ns: float
    exp_ns: float
    exp_block_ns: float
    fma_ns: float
    n_exp: int
    n_fma_mean: int
    n_fma_forward: int
    forward_latent_ns: float = float("nan")
    n_fma_band: int = 0

    @property
    def floor_mean_ns(self) -> float:
        """M exp (the export's own exp block) + the mean's multiply-adds."""
        return self.exp_block_ns + self.n_fma_mean * self.fma_ns

    @property
    def floor_mean_libm_ns(self) -> float:
        """The same with libm's scalar ``exp``."""
        return self.exp_ns + self.n_fma_mean * self.fma_ns

    @property
    def floor_forward_ns(self) -> float:
        return self.exp_block_ns + self.n_fma_forward * self.fma_ns


def time_c_predictor(sources: dict[str, str], x: np.ndarray, *, kind: str, prefix: str = "bem",
                     calls: int = 200, batches: int = 200, flag_sets: dict[str, tuple[str, ...]] = FLAG_SETS) -> list[CTiming]:
    """Compile ``sources`` (from :func:`~bemlearn.export.c_source.c_sources`) with the harness and time it.

    Args:
        sources: ``{file name: text}`` of the C predictor.
        x: ``(B, 3m)`` in-range queries (physical units), cycled through.
        kind: the GP kind (counts the std's multiply-adds).
        calls, batches: calls per timed batch, batches (median taken).
        flag_sets: ``{label: flags}`` builds to time.
    """
    cc = find_cc()
    if cc is None:
        raise EnvironmentProblem("time_c_predictor: no C compiler found (set $CC or install cc)")
    header = next(t for k, t in sources.items() if k.endswith(".h"))
    found = re.search(r"_N_SUPPORT (\d+)", header)
    assert found is not None  # c_sources always writes the define
    n, M = x.shape[1], int(found.group(1))
    n_fma_mean = M * (n + 1)
    n_fma_band = n * M if re.search(rf"#define {prefix.upper()}_BANDED 1\b", header) else 0
    n_est = re.search(rf"#define {prefix.upper()}_N_ESTIMATORS (\d+)", header)
    n_fma_band += (int(n_est.group(1)) if n_est else 0) * M       # the estimator term: K multiply-adds per support point
    factored = any(f"{prefix}_inner[" in t for t in sources.values())   # sparse S = L⁻ᵀ C L⁻¹: solve, then C's factor
    from bemlearn.models.gp_kinds import gp_class

    n_fma_var = M * M + (M * (M + 1) // 2 if factored else 0) if gp_class(kind).sparse else M * (M + 1) // 2
    n_fma_forward = n_fma_mean + n_fma_var + n_fma_band
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, text in sources.items():
            Path(tmp, name).write_text(text)
        Path(tmp, "harness.c").write_text(HARNESS.replace("@P@", prefix).replace("@U@", prefix.upper()))
        stdin = " ".join(repr(float(v)) for v in x.reshape(-1))
        for label, flags in flag_sets.items():
            exe = Path(tmp) / "harness"
            cmd = [cc, *flags, "-o", str(exe), str(Path(tmp) / "harness.c"), "-lm"]
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode != 0:
                raise EnvironmentProblem(f"time_c_predictor: {' '.join(cmd)} failed:\n{res.stderr}")
            res = subprocess.run([str(exe), str(len(x)), str(calls), str(batches), str(n_fma_forward)],
                                 input=stdin, check=True, capture_output=True, text=True)
            vals = dict(line.split()[:2] for line in res.stdout.splitlines())
            out.append(CTiming(label, float(vals["mean_ns"]), float(vals["forward_ns"]), float(vals["exp_ns_per_query"]),
                               float(vals["expblock_ns_per_query"]), float(vals["fma_ns"]), M, n_fma_mean, n_fma_forward,
                               float(vals["forward_latent_ns"]), n_fma_band))
    return out
