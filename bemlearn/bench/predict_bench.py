"""``bemlearn bench predict``: latency, throughput and parity of the exported BEM predictor.

Measured for one model (a checkpoint, or by default a synthetic 500-point exact GP with
d = 5, m = 1), each single-query case B = 1 on ``threads`` threads (default 1), timed call
by call with ``time.perf_counter_ns`` after a warm-up; median and p99 in µs.  The TorchScript
and NumPy cases are timed in 10 alternating rounds, so their ratios hold under changing load:

* the TorchScript artifact's ``forward`` (mean and std) and ``bem_mean``, loaded from disk;
* the same through the ``.pt2`` (torch.export) artifact;
* NumPy on the *same formulas* (the folded constants of
  :class:`~bemlearn.export.folded_posterior.FoldedPosterior`: e = W [v, v∘v] + c,
  μ = y₀ + w·exp(e); std with a precomputed factor R = L⁻¹, one dense matvec), and NumPy on
  the textbook formulas (k_j = σ_f² exp(−½‖(x̃ − z_j)/ℓ‖²), μ = y_mean + y_std kᵀα);
* the GPyTorch ExactGP (eval mode, ``torch.no_grad``) rebuilt from the posterior (exact GPs:
  Z = X, targets Y = (K_ZZ + σ_0² I) α), default settings and with ``fast_pred_var``;

* an empty TorchScript method (``x -> x``): the fixed cost of calling a TorchScript module
  from Python, which no formula can go below;

* the C export (``bemlearn export --format c``) compiled with the system ``cc`` and timed in a
  C loop, with its arithmetic floor (:mod:`bemlearn.bench.c_timing`), and its parity with the
  TorchScript methods on 3000 in-range inputs (:mod:`bemlearn.bench.c_parity`);

plus the time of 10⁵ queries in one batch on ``batch_threads`` threads (default: every core),
with the floor of the exact variance: the triangular solve v = L⁻¹k alone on the same batch
(B·M² flops, memory- and BLAS-bound), and parity of the TorchScript ``forward`` with that
GPyTorch model on 10⁴ random inputs.  Latency depends on other load on the machine: the
result records ``/proc/loadavg`` before and after.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from bemlearn.bench.c_parity import c_parity, in_range_inputs
from bemlearn.bench.c_timing import CTiming, time_c_predictor
from bemlearn.bench.cpp_timing import CppTiming, time_cpp_predictors
from bemlearn.export.aoti import aoti_bytes, find_cxx, load_aoti_predictor
from bemlearn.export.bem_predictor import BEMPredictor
from bemlearn.export.c_build import find_cc
from bemlearn.export.c_source import c_sources
from bemlearn.export.checkpoint import load_checkpoint
from bemlearn.export.export_run import AOTI_NAME
from bemlearn.export.metadata import PredictorMetadata
from bemlearn.export.pt2 import load_pt2_predictor, save_pt2
from bemlearn.export.torchscript import load_torchscript, quiet_jit, save_torchscript
from bemlearn.export.verify import verify_predictor
from bemlearn.models.predictor_state import PredictorState
from bemlearn.threads import torch_threads

__all__ = ["Latency", "PredictBenchResult", "run_predict_bench", "format_predict_bench", "synthetic_posterior"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Latency:
    """Per-call latency of one case: median and 99th percentile over ``n`` calls, µs."""

    name: str
    median_us: float
    p99_us: float
    n: int


@dataclass(frozen=True)
class PredictBenchResult:
    """Everything ``bemlearn bench predict`` prints (see :func:`format_predict_bench`)."""

    model: str
    threads: int
    latencies: dict[str, Latency]
    batch: int
    batch_seconds: dict[str, float]
    batch_threads: int
    parity: dict[str, float]
    loadavg: tuple[str, str]
    notes: list[str] = field(default_factory=list)
    c_timings: list[CTiming] = field(default_factory=list)
    c_parity: dict[str, float] = field(default_factory=dict)
    export_seconds: dict[str, float] = field(default_factory=dict)
    aoti_parity: dict[str, float] = field(default_factory=dict)
    cpp: CppTiming | None = None


def synthetic_posterior(*, n_train: int = 500, m: int = 1, seed: int = 0, noise: float = 1e-3) -> tuple[PredictorState, PredictorMetadata]:
    """An exact-GP posterior on synthetic Furuta-like data (d = 3m + 2), for benchmarks and tests.

    Inputs x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u] ~ N(0, diag(20, 3, 1, 30, 2)²) (rad/s², rad/s, rad);
    target q_u = 0.05 tanh(q̈_a1 / 20) + 0.02 sin(q_a1) + 0.001 q̈_u / 30 + 10⁻³ N(0, 1) rad.
    Hyperparameters are fixed (ℓ = 1.5, σ_f² = 1, σ_0² = ``noise``, normalized units), and
    α = K⁻¹ỹ, S = K⁻¹ follow from a dense Cholesky of K = K_ZZ + σ_0² I.
    """
    g = torch.Generator().manual_seed(seed)
    f64: dict[str, Any] = dict(dtype=torch.float64)
    d = 3 * m + 2
    scales = torch.tensor([20.0] * m + [3.0] * m + [1.0] * m + [30.0, 2.0], **f64)
    X = torch.randn(n_train, d, generator=g, **f64) * scales
    y = 0.05 * torch.tanh(X[:, 0] / 20) + 0.02 * torch.sin(X[:, 2 * m]) + 0.001 * X[:, 3 * m] / 30
    y = y + 1e-3 * torch.randn(n_train, generator=g, **f64)
    x_mean, x_std, y_mean, y_std = X.mean(0), X.std(0), y.mean(), y.std()
    names = tuple(
        [f"qdd_a{i}" for i in range(m)] + [f"qd_a{i}" for i in range(m)] + [f"q_a{i}" for i in range(m)] + ["qdd_u", "qd_u"]
    )
    state = PredictorState(
        kind="exact", Z=(X - x_mean) / x_std, alpha=torch.zeros(n_train, **f64), S=torch.zeros(n_train, n_train, **f64),
        lengthscale=torch.full((d,), 1.5, **f64), outputscale=torch.tensor(1.0, **f64), noise=torch.tensor(noise, **f64),
        x_mean=x_mean, x_std=x_std, y_mean=y_mean, y_std=y_std, input_names=names, n_train=n_train,
    )
    L = torch.linalg.cholesky(state.gram())
    alpha = torch.cholesky_solve(((y - y_mean) / y_std)[:, None], L)[:, 0]
    state = dataclasses.replace(state, alpha=alpha, S=torch.cholesky_inverse(L))
    units = {n: "rad/s^2" if n.startswith("qdd") else "rad/s" if n.startswith("qd") else "rad" for n in names}
    actuated = tuple(f"a{i}" for i in range(m))
    meta = PredictorMetadata(
        robot="synthetic", joint_names=(*actuated, "u"), actuated_names=actuated, unactuated_name="u", m=m,
        input_names=names, units=units, n_train=n_train, n_inducing=None,
        hyperparameters={"lengthscale": 1.5, "outputscale": 1.0, "noise": noise},
        bemlearn_version="synthetic", data_sha256=hashlib.sha256(X.numpy().tobytes() + y.numpy().tobytes()).hexdigest(),
    )
    return state, meta


def _gpytorch_exact(state: PredictorState) -> Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]:
    """GPyTorch ExactGP with the posterior of ``state`` (exact kind); returns x_bem ↦ (mean, std)."""
    import gpytorch

    d = state.dim

    class _ExactGP(gpytorch.models.ExactGP):
        def __init__(self, x: torch.Tensor, y: torch.Tensor, lik: gpytorch.likelihoods.GaussianLikelihood) -> None:
            super().__init__(x, y, lik)
            self.mean_module = gpytorch.means.ZeroMean()
            self.covar_module = gpytorch.kernels.ScaleKernel(gpytorch.kernels.RBFKernel(ard_num_dims=d))

        def forward(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
            return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))

    lik = gpytorch.likelihoods.GaussianLikelihood(noise_constraint=gpytorch.constraints.GreaterThan(1e-12)).double()
    targets = state.gram() @ state.alpha
    model = _ExactGP(state.Z, targets, lik).double()
    model.covar_module.base_kernel.lengthscale = state.lengthscale
    model.covar_module.outputscale = state.outputscale
    lik.noise = state.noise
    model.eval()
    lik.eval()
    zeros = torch.zeros(1, 2, dtype=torch.float64)

    def predict(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        xf = torch.cat([x, zeros.expand(x.shape[0], 2)], 1)
        with torch.no_grad(), gpytorch.settings.max_cholesky_size(10**9):
            f = model((xf - state.x_mean) / state.x_std)
            return state.y_mean + state.y_std * f.mean, state.y_std * f.variance.sqrt()

    return predict


def _numpy_baselines(predictor: BEMPredictor, state: PredictorState) -> dict[str, Callable[[np.ndarray], Any]]:
    """NumPy versions of the same math for one query ``x: (1, 3m)``."""
    b = predictor.bem
    a, nb, c, w, W = (t.numpy() for t in (b.a, b.nb, b.c, b.w, b.W))
    offset, var0, centered = float(b.offset[0]), b.var0, b.centered
    gain = float(state.y_std * state.outputscale)
    L = torch.linalg.cholesky(state.gram())
    R = np.zeros((state.n_support, state.n_support + 1))
    R[:, :-1] = gain * torch.linalg.solve_triangular(L, torch.eye(state.n_support, dtype=torch.float64), upper=False).numpy()
    zs = (state.Z / state.lengthscale).numpy()
    x_mean, x_std, ls = state.x_mean.numpy(), state.x_std.numpy(), state.lengthscale.numpy()
    alpha, sf2, y_mean, y_std = state.alpha.numpy(), float(state.outputscale), float(state.y_mean), float(state.y_std)
    R_plain = R[:, :-1] / gain

    def folded_mean(x: np.ndarray) -> float:
        v = x[0] * a + nb if centered else x[0]
        return offset + np.exp(W @ np.concatenate([v, v * v]) + c) @ w

    def folded_forward(x: np.ndarray) -> tuple[float, float]:
        v = x[0] * a + nb if centered else x[0]
        k = np.exp(W @ np.concatenate([v, v * v]) + c)
        r = R @ k
        return offset + k @ w, np.sqrt(max(var0 - r @ r, 0.0))

    def _k(x: np.ndarray) -> np.ndarray:
        xt = (np.concatenate([x[0], [0.0, 0.0]]) - x_mean) / x_std / ls
        return sf2 * np.exp(-0.5 * ((zs - xt) ** 2).sum(1))

    def plain_mean(x: np.ndarray) -> float:
        return y_mean + y_std * (_k(x) @ alpha)

    def plain_forward(x: np.ndarray) -> tuple[float, float]:
        k = _k(x)
        v = R_plain @ k
        return y_mean + y_std * (k @ alpha), y_std * np.sqrt(max(sf2 - v @ v, 0.0))

    return {"numpy folded bem_mean": folded_mean, "numpy folded forward": folded_forward,
            "numpy textbook bem_mean": plain_mean, "numpy textbook forward": plain_forward}


def _timings(fn: Callable[[Any], Any], x: Any, repeats: int) -> np.ndarray:
    ts = np.empty(repeats)
    clock = time.perf_counter_ns
    for i in range(repeats):
        t0 = clock()
        fn(x)
        ts[i] = clock() - t0
    return ts


def _latency(name: str, fn: Callable[[Any], Any], x: Any, *, repeats: int, warmup: int) -> Latency:
    for _ in range(warmup):
        fn(x)
    ts = _timings(fn, x, repeats)
    return Latency(name, float(np.median(ts)) / 1e3, float(np.percentile(ts, 99)) / 1e3, repeats)


def _interleaved(
    cases: dict[str, tuple[Callable[[Any], Any], Any]], *, repeats: int, warmup: int, rounds: int = 10
) -> dict[str, Latency]:
    """Latency of several cases timed in alternating rounds, so that a change of background
    load during the run affects all of them alike (their ratios are what the targets use)."""
    for fn, x in cases.values():
        for _ in range(warmup):
            fn(x)
    per_round = max(repeats // rounds, 1)
    samples: dict[str, list[np.ndarray]] = {name: [] for name in cases}
    for _ in range(rounds):
        for name, (fn, x) in cases.items():
            samples[name].append(_timings(fn, x, per_round))
    out = {}
    for name, parts in samples.items():
        ts = np.concatenate(parts)
        out[name] = Latency(name, float(np.median(ts)) / 1e3, float(np.percentile(ts, 99)) / 1e3, ts.size)
    return out


@contextlib.contextmanager
def _threads(n: int) -> Iterator[list[str]]:
    """torch and (if threadpoolctl is installed) NumPy's BLAS limited to ``n`` threads."""
    notes: list[str] = []
    with torch_threads(n):
        try:
            from threadpoolctl import threadpool_limits
        except ImportError:
            notes.append("threadpoolctl not installed: NumPy's BLAS thread count not limited")
            limiter = contextlib.nullcontext()
        else:
            limiter = threadpool_limits(n)
        with limiter:
            yield notes


def _loadavg() -> str:
    try:
        return Path("/proc/loadavg").read_text().strip()
    except OSError:
        return "n/a"


def run_predict_bench(
    *,
    checkpoint: str | os.PathLike[str] | None = None,
    n_train: int = 500,
    seed: int = 0,
    repeats: int = 20000,
    warmup: int = 2000,
    gpytorch_repeats: int = 200,
    batch: int = 100_000,
    n_parity: int = 10_000,
    threads: int = 1,
    batch_threads: int | None = None,
    pt2: bool = True,
    progress: bool = True,
    c: bool = True,
    aoti: bool = True,
    cpp: bool = True,
) -> PredictBenchResult:
    """Run the benchmark (see module docstring) and return the numbers.

    Args:
        checkpoint: a run directory or checkpoint file; ``None`` uses
            :func:`synthetic_posterior` with ``n_train`` points (d = 5, m = 1).
        repeats, warmup: timed and untimed calls per single-query case.
        gpytorch_repeats: timed calls of the (slow) GPyTorch model.
        batch: queries in the throughput case.
        n_parity: random inputs for the GPyTorch parity check (exact GPs only).
        threads: torch / BLAS threads for the latency cases.
        batch_threads: torch / BLAS threads for the batch case (``None``: ``os.cpu_count()``).
        pt2: also time the torch.export artifact (exporting takes a few seconds).
        progress: show a tqdm bar over the cases.
        c: also time the C export (:mod:`bemlearn.bench.c_timing`; needs a C compiler).
        aoti: also compile the AOTInductor package (:mod:`bemlearn.export.aoti`, 1–2 min) and time it
            from Python, in the same alternating rounds as TorchScript; check it against the dense
            posterior (:func:`~bemlearn.export.verify.verify_predictor`) and TorchScript.
        cpp: with ``aoti``, also time both artifacts from C++ (:mod:`bemlearn.bench.cpp_timing`;
            builds a libtorch program, ≈ 30–60 s).
    """
    if checkpoint is None:
        state, meta = synthetic_posterior(n_train=n_train, seed=seed)
        model = f"synthetic exact GP, N = {n_train}, d = {state.dim}, m = {meta.m}"
    else:
        ckpt = load_checkpoint(checkpoint)
        state, meta = ckpt.predictor_state, ckpt.metadata
        model = f"{ckpt.path}: {state.kind} GP, M = {state.n_support}, d = {state.dim}, m = {meta.m}"
    predictor = BEMPredictor(state, meta)
    n_batch = batch_threads or os.cpu_count() or 1
    load_before = _loadavg()
    g = torch.Generator().manual_seed(seed)
    n_bem = 3 * meta.m
    scale = state.x_std[:n_bem]
    x1 = (state.x_mean[:n_bem] + 0.5 * scale * torch.randn(1, n_bem, generator=g, dtype=torch.float64)).contiguous()
    xb = state.x_mean[:n_bem] + scale * torch.randn(batch, n_bem, generator=g, dtype=torch.float64)
    xp = state.x_mean[:n_bem] + 2 * scale * torch.randn(n_parity, n_bem, generator=g, dtype=torch.float64)
    gp = None if state.sparse else _gpytorch_exact(state)
    lat: dict[str, Latency] = {}
    c_timings: list[CTiming] = []
    c_par: dict[str, float] = {}
    batch_s: dict[str, float] = {}
    parity: dict[str, float] = {}
    export_s: dict[str, float] = {}
    aoti_par: dict[str, float] = {}
    cpp_timing: CppTiming | None = None
    with tempfile.TemporaryDirectory() as tmp, _threads(threads) as notes:
        t0 = time.perf_counter()
        ts_path = save_torchscript(predictor, Path(tmp) / "bem_predictor.pt")
        export_s["torchscript (.pt)"] = time.perf_counter() - t0
        ts = load_torchscript(ts_path)
        with quiet_jit():
            empty = torch.jit.script(_Identity())
        single: dict[str, tuple[Callable[[Any], Any], Any]] = {
            "torchscript empty call (x -> x)": (empty, x1),
            "torchscript forward": (ts.forward, x1),
            "torchscript bem_mean": (ts.bem_mean, x1),
        }
        if hasattr(ts, "forward_latent"):   # the same module's mean + latent std: the forward before the band
            single["torchscript forward_latent"] = (ts.forward_latent, x1)
        aoti_path = None
        if aoti and find_cxx() is None:
            notes.append("no C++ compiler: AOTInductor package not compiled")
        elif aoti:
            t0 = time.perf_counter()
            data = aoti_bytes(predictor)
            export_s["AOTInductor package (.pt2, 6 methods)"] = time.perf_counter() - t0
            aoti_path = Path(tmp) / AOTI_NAME
            aoti_path.write_bytes(data)
            ao = load_aoti_predictor(aoti_path)
            single["aoti forward"] = (ao.forward, x1)
            single["aoti bem_mean"] = (ao.bem_mean, x1)
            dm, dv = verify_predictor(ao, state, n=1000, seed=seed)
            ts_mean, ts_std = ts.forward(xp)
            ao_mean, ao_std = ao.forward(xp)
            aoti_par = {"n": 1000.0, "mean_abs_vs_dense": dm, "var_rel_vs_dense": dv, "n_ts": float(n_parity),
                        "mean_abs_vs_torchscript": float((ao_mean - ts_mean).abs().max()),
                        "std_rel_vs_torchscript": float(((ao_std - ts_std) / ts_std).abs().max()),
                        "bem_mean_abs_vs_torchscript": float((ao.bem_mean(xp) - ts.bem_mean(xp)).abs().max())}
        single |= {name: (fn, x1.numpy()) for name, fn in _numpy_baselines(predictor, state).items()}
        steps = ["single", *(["cpp"] if cpp and aoti_path is not None else []), *(["c"] if c else []), *(["pt2"] if pt2 else []), *(["gpytorch"] if gp is not None else []), "batch"]
        for step in tqdm(steps, desc="bench predict", disable=not progress, leave=False):
            if step == "single":
                lat.update(_interleaved(single, repeats=repeats, warmup=warmup))
            elif step == "cpp":
                assert aoti_path is not None   # the step is listed with a package only
                cpp_timing = time_cpp_predictors(ts_path, aoti_path, x1[0].tolist(), rounds=10, per_round=max(repeats // 10, 10))
            elif step == "c":
                if find_cc() is None:
                    notes.append("no C compiler: C export not timed")
                    continue
                xc = np.concatenate([x1.numpy(), xb[:63].numpy()])
                c_src = c_sources(state, meta)
                c_timings = time_c_predictor(c_src, xc, kind=state.kind, calls=100, batches=max(repeats // 100, 5))
                c_par = c_parity(c_src, ts, in_range_inputs(state, 3000, seed=seed), n_bem=n_bem)
            elif step == "pt2":
                t0 = time.perf_counter()
                p2_path = save_pt2(predictor, Path(tmp) / "bem_predictor.pt2")
                export_s["torch.export (.pt2)"] = time.perf_counter() - t0
                p2 = load_pt2_predictor(p2_path)
                n2 = max(repeats // 10, 100)
                for name, fn in (("pt2 forward", p2.forward), ("pt2 bem_mean", p2.bem_mean)):
                    lat[name] = _latency(name, fn, x1, repeats=n2, warmup=min(warmup, n2))
            elif step == "gpytorch":
                assert gp is not None  # the step is listed for exact GPs only
                lat.update(_gpytorch_latency(gp, x1, repeats=gpytorch_repeats))
                m_ref, s_ref = (torch.cat(t) for t in zip(*(gp(c) for c in xp.split(2000))))
                # GPyTorch gives the latent std; forward's std is the calibrated band (docs/uncertainty.md)
                m_ts, s_ts = (ts.forward_latent if hasattr(ts, "forward_latent") else ts.forward)(xp)
                m_ld = _extended_precision_mean(state, xp)
                parity = {
                    "n": float(n_parity),
                    "mean_abs": float((m_ts - m_ref).abs().max()),
                    "std_rel": float(((s_ts - s_ref) / s_ref).abs().max()),
                    "mean_abs_ours_vs_extended": float(np.abs(m_ts.numpy() - m_ld).max()),
                    "mean_abs_gpytorch_vs_extended": float(np.abs(m_ref.numpy() - m_ld).max()),
                    "cond_K": float(torch.linalg.cond(state.gram())),
                }
            else:
                with _threads(n_batch):
                    for name, fn in (("torchscript forward", ts.forward), ("torchscript bem_mean", ts.bem_mean)):
                        batch_s[name] = _batch_seconds(fn, xb)
                    if predictor.bem.triangular:
                        batch_s["floor: v = L⁻¹k alone"] = _solve_floor(predictor, xb)
    return PredictBenchResult(model, threads, lat, batch, batch_s, n_batch, parity, (load_before, _loadavg()), notes, c_timings,
                              c_par, export_s, aoti_par, cpp_timing)


def _extended_precision_mean(state: PredictorState, x: torch.Tensor) -> np.ndarray:
    """μ(x_0^e) = y_mean + y_std Σ_j α_j k_j (eq. 12, 14) of ``state``'s own α in NumPy ``longdouble``.

    The reference for the mean parity: the rebuilt GPyTorch model re-solves K α' = K α, so
    its mean carries an error of about cond(K)·ε·‖α‖ that neither side can remove.
    """
    ld = np.longdouble
    n = x.shape[1]
    xt: np.ndarray = np.zeros((x.shape[0], state.dim), dtype=ld)
    xt[:, :n] = x.numpy()
    xt = (xt - state.x_mean.numpy().astype(ld)) / state.x_std.numpy().astype(ld) / state.lengthscale.numpy().astype(ld)
    zs = state.Z.numpy().astype(ld) / state.lengthscale.numpy().astype(ld)
    alpha = state.alpha.numpy().astype(ld)
    out = np.empty(x.shape[0], dtype=ld)
    for i in range(0, x.shape[0], 500):
        d2 = ((xt[i : i + 500, None, :] - zs[None]) ** 2).sum(-1)
        out[i : i + 500] = (ld(float(state.outputscale)) * np.exp(-0.5 * d2)) @ alpha
    return ld(float(state.y_mean)) + ld(float(state.y_std)) * out


class _Identity(torch.nn.Module):
    """``x -> x``: the fixed cost of a call into a TorchScript module."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x


def _solve_floor(predictor: BEMPredictor, xb: torch.Tensor) -> float:
    """Median seconds of the exact variance's triangular solve alone, in the predictor's row blocks."""
    post = predictor.bem
    blocks = [post._kernel(c) for c in xb.split(post.chunk)]

    def solve(_: Any) -> None:
        for k in blocks:
            torch.linalg.solve_triangular(post.FT, k, upper=True, left=False)

    return _batch_seconds(solve, xb)


def _gpytorch_latency(gp: Callable[[torch.Tensor], Any], x1: torch.Tensor, *, repeats: int) -> dict[str, Latency]:
    import gpytorch

    out = {"gpytorch forward": _latency("gpytorch forward", gp, x1, repeats=repeats, warmup=5)}
    with gpytorch.settings.fast_pred_var():
        name = "gpytorch forward (fast_pred_var)"
        out[name] = _latency(name, gp, x1, repeats=repeats, warmup=5)
    return out


def _batch_seconds(fn: Callable[[torch.Tensor], Any], xb: torch.Tensor) -> float:
    """Median wall time of 3 calls on the whole batch (after one small warm-up call)."""
    fn(xb[:1000])
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        fn(xb)
        runs.append(time.perf_counter() - t0)
    return float(np.median(runs))


def _format_c(result: PredictBenchResult) -> list[str]:
    """The C export's rows: per-call µs in a C loop, the ratio to TorchScript from Python, the floor."""
    if not result.c_timings:
        return []
    ts = result.latencies.get("torchscript bem_mean")
    t0 = result.c_timings[0]
    lines = [f"C export, single queries in a C loop (one thread; floor = {t0.n_exp} exp + {t0.n_fma_mean} multiply-adds "
             f"for the mean, + {t0.n_fma_forward - t0.n_fma_mean} for the std, of which {t0.n_fma_band} for the band's "
             "gradient and estimator terms):",
             f"  {'build':20s} {'mean µs':>9s} {'forward µs':>11s} {'fwd_latent µs':>14s} {'floor mean µs':>14s} "
             f"{'mean/floor':>11s} {'libm-exp floor µs':>18s} {'C mean / TS bem_mean':>21s}"]
    for t in result.c_timings:
        ratio = f"{t.mean_ns / 1e3 / ts.median_us:.3f}" if ts else "n/a"
        lines.append(f"  {t.flags:20s} {t.mean_ns / 1e3:9.3f} {t.forward_ns / 1e3:11.2f} {t.forward_latent_ns / 1e3:14.2f} "
                     f"{t.floor_mean_ns / 1e3:14.3f} {t.mean_ns / t.floor_mean_ns:11.2f} {t.floor_mean_libm_ns / 1e3:18.3f} "
                     f"{ratio:>21s}")
    lines.append("  (target: C bem_mean <= 0.25x TorchScript bem_mean from Python); per exp and multiply-add, ns:")
    for t in result.c_timings:
        lines.append(f"    {t.flags:20s} own exp {t.exp_block_ns / t.n_exp:.3f}, libm exp {t.exp_ns / t.n_exp:.3f}, "
                     f"multiply-add {t.fma_ns:.4f}")
    par = result.c_parity
    if par:
        lines.append(f"  C (-O2) vs TorchScript on {int(par['n'])} in-range inputs (targets: mean 1e-10 rad, std 1e-8 relative):")
        for key, name in (("forward", "bem_forward / forward"), ("full", "bem_predict_full / predict_full")):
            lines.append(f"    {name:34s} max |Δmean| {par[key + '_mean_abs']:.2e} rad, max |Δstd|/std {par[key + '_std_rel']:.2e} "
                         f"(band), {par[key + '_latent_std_rel']:.2e} (latent, *_latent)")
    lines.append("")
    return lines


def _format_aoti(result: PredictBenchResult) -> list[str]:
    """Export times, the AOTInductor package against TorchScript from Python and from C++, its parity."""
    lat, lines = result.latencies, []
    if result.export_seconds:
        lines.append("export time (serialize; AOTInductor: export + C++ compile of every method):")
        lines += [f"  {name:42s} {sec:8.1f} s" for name, sec in result.export_seconds.items()]
    for method in ("forward", "bem_mean"):
        a, t = lat.get(f"aoti {method}"), lat.get(f"torchscript {method}")
        if a and t:
            lines.append(f"AOTI {method} / TorchScript {method} (Python):{' ' * (11 - len(method))}{a.median_us / t.median_us:.2f}"
                         "    (target <= 0.6)")
    if result.cpp is not None:
        cl = result.cpp.latencies
        lines.append(f"from C++ (libtorch, one thread; harness built in {result.cpp.build_seconds:.0f} s):")
        lines.append(f"  {'case (B = 1)':40s} {'median µs':>10s} {'p99 µs':>10s}")
        lines += [f"  {name:40s} {med:10.2f} {p99:10.2f}" for name, (med, p99) in cl.items()]
        for method in ("forward", "bem_mean"):
            ca, ct = cl.get(f"aoti {method}"), cl.get(f"torchscript {method}")
            if ca and ct:
                lines.append(f"  AOTI {method} / TorchScript {method} (C++):{' ' * (11 - len(method))}{ca[0] / ct[0]:.2f}"
                             "    (target <= 1)")
        v = result.cpp.values
        if "aoti forward" in v and "torchscript forward" in v:
            d = max(abs(p - q) for p, q in zip(v["aoti forward"] + v["aoti bem_mean"], v["torchscript forward"] + v["torchscript bem_mean"]))
            lines.append(f"  C++ AOTI vs C++ TorchScript on the timed query: max |Δ| {d:.2e} rad")
    par = result.aoti_parity
    if par:
        lines.append(f"AOTI parity: vs the dense posterior on {int(par['n'])} inputs (every method): max |Δmean| "
                     f"{par['mean_abs_vs_dense']:.2e} rad (target 1e-10), max rel |Δvar| {par['var_rel_vs_dense']:.2e}; "
                     f"vs TorchScript on {int(par['n_ts'])}: forward |Δmean| {par['mean_abs_vs_torchscript']:.2e} rad, "
                     f"|Δstd|/std {par['std_rel_vs_torchscript']:.2e}, bem_mean |Δ| {par['bem_mean_abs_vs_torchscript']:.2e} rad")
    return [*lines, ""] if lines else []


def format_predict_bench(result: PredictBenchResult) -> str:
    """The report table, with the ratios the targets are stated in."""
    lat = result.latencies
    lines = [f"model: {result.model}", f"threads: {result.threads}   loadavg before: {result.loadavg[0]}   after: {result.loadavg[1]}", ""]
    lines.append(f"{'single query (B = 1)':42s} {'median µs':>10s} {'p99 µs':>10s}")
    for row in lat.values():
        lines.append(f"{row.name:42s} {row.median_us:10.2f} {row.p99_us:10.2f}")

    def ratio(a: str, b: str) -> str:
        return f"{lat[a].median_us / lat[b].median_us:.2f}" if a in lat and b in lat else "n/a"

    lines += [
        "",
        f"GPyTorch forward / TorchScript forward:          {ratio('gpytorch forward', 'torchscript forward')}x   (target >= 30)",
        f"TorchScript forward / NumPy folded forward:       {ratio('torchscript forward', 'numpy folded forward')}    (target <= 1.5)",
        f"TorchScript forward (band) / forward_latent:      {ratio('torchscript forward', 'torchscript forward_latent')}    "
        "(target <= 1.5: the calibrated band's cost over the latent std)",
        f"TorchScript forward / NumPy textbook forward:     {ratio('torchscript forward', 'numpy textbook forward')}",
        f"TorchScript bem_mean / NumPy folded bem_mean:     {ratio('torchscript bem_mean', 'numpy folded bem_mean')}    (target <= 1; and <= 25 µs)",
        f"TorchScript bem_mean / NumPy textbook bem_mean:   {ratio('torchscript bem_mean', 'numpy textbook bem_mean')}",
        f"empty TorchScript call / NumPy folded bem_mean:   {ratio('torchscript empty call (x -> x)', 'numpy folded bem_mean')}"
        "    (the call alone, before any formula)",
        "",
    ]
    lines += _format_aoti(result)
    lines += _format_c(result)
    lines.append(f"batch of {result.batch} queries on {result.batch_threads} thread(s) (target: 1e5 in <= 0.5 s):")
    for name, sec in result.batch_seconds.items():
        lines.append(f"  {name:38s} {sec:.3f} s")
    if result.parity:
        lines.append(
            f"parity with GPyTorch on {int(result.parity['n'])} inputs: max |Δmean| = {result.parity['mean_abs']:.2e} rad "
            f"(target 1e-10), max rel |Δstd| = {result.parity['std_rel']:.2e} (target 1e-8)"
        )
        lines.append(
            f"  mean against the same posterior in extended precision (NumPy longdouble, α of the model): "
            f"TorchScript {result.parity['mean_abs_ours_vs_extended']:.2e} rad, GPyTorch "
            f"{result.parity['mean_abs_gpytorch_vs_extended']:.2e} rad (it re-solves K α' = K α; cond K = "
            f"{result.parity['cond_K']:.1e})"
        )
    lines += [f"note: {n}" for n in result.notes]
    return "\n".join(lines)
