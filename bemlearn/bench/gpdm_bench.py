"""GPDM benchmark on synthetic gait data with a known phase vector c (paper Sec. III-C).

``synthetic_gait`` builds sequences whose true latent is exactly linear in the joints,
c_true·(q − q_0) = χ, so a fitted GPDM can be scored by the cosine between its c and
c_true and the correlation between its latents and χ:

    χ_{t+1} = χ_t + h (1 + v sin(π χ_t)),   h = 2 / (T − 1)     (1-D zero dynamics)
    q_t = q_0 + c_true χ_t / ‖c_true‖² + U φ(χ_t) + ε_t,   Uᵀ c_true = 0,  UᵀU = I,
    φ(χ) = A [cos πχ, sin πχ, cos 2πχ, sin 2πχ, cos 3πχ, …]  (n − 1 entries).

The curved part φ lies in the complement of c_true and is not monotone in χ, so only
projections close to c_true are one-to-one in χ; it also carries most of the variance,
so the first principal direction is far from c_true.

Run ``python -m bemlearn.bench.gpdm_bench`` (``--help`` for options); it prints one JSON
line with the fit time, the recovery scores and the load average (other processes on
the machine change the time).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass

import torch

from bemlearn.bench.train_bench import peak_rss_mib
from bemlearn.errors import ArgumentError
from bemlearn.fitting.gpdm_fit import GPDMConfig, fit_gpdm
from bemlearn.models.gpdm import compare_latents
from bemlearn.threads import torch_threads

__all__ = ["SyntheticGait", "synthetic_gait", "run_gpdm_bench", "main"]

#: The robot gait vector reported in the paper (Sec. IV-B), [q1 … q5].
PAPER_ROBOT_C = (-0.82, 0.97, -0.72, -4.09, 5.91)


@dataclass(frozen=True)
class SyntheticGait:
    """Synthetic sequences with a known latent (see module docstring).

    Attributes:
        Q_list: one (T, n) float64 tensor per sequence, joint angles, rad.
        chi_list: the true latents, one (T,) tensor per sequence.
        c_true: (n,) the true gait vector, c_true·(q − q_0) = χ up to the noise ε, 1/rad.
        q0: (n,) the joint offset q_0, rad.
    """

    Q_list: list[torch.Tensor]
    chi_list: list[torch.Tensor]
    c_true: torch.Tensor
    q0: torch.Tensor


def synthetic_gait(
    *,
    n_seq: int = 3,
    steps: int = 100,
    n_joints: int = 5,
    amplitude: float = 0.2,
    speed_variation: float = 0.3,
    noise_std: float = 1e-3,
    seed: int = 0,
) -> SyntheticGait:
    """Sequences from a known 1-D zero dynamics and a known c (module docstring).

    Args:
        n_seq: number of sequences (gait steps), each starting at χ_0 ∈ [−1, −0.8].
        steps: samples per sequence T (≥ 2).
        n_joints: n ≥ 2; with n = 5, c_true is the paper's robot vector.
        amplitude: A, amplitude of the curved components, rad.
        speed_variation: v in the latent dynamics, |v| < 1 keeps χ increasing.
        noise_std: standard deviation of the i.i.d. joint noise ε, rad.
        seed: seeds c_true (n ≠ 5), U, q_0, χ_0 and ε.
    """
    if n_seq < 1 or steps < 2 or n_joints < 2 or not abs(speed_variation) < 1:
        raise ArgumentError("synthetic_gait: expected n_seq ≥ 1, steps ≥ 2, n_joints ≥ 2, |speed_variation| < 1")
    gen = torch.Generator().manual_seed(seed)
    f64 = torch.float64
    if n_joints == len(PAPER_ROBOT_C):
        c_true = torch.tensor(PAPER_ROBOT_C, dtype=f64)
    else:
        c_true = torch.randn(n_joints, generator=gen, dtype=f64)
    others = torch.randn(n_joints, n_joints - 1, generator=gen, dtype=f64)
    basis, _ = torch.linalg.qr(torch.cat([c_true[:, None], others], dim=1))
    U = basis[:, 1:]  # (n, n−1), orthonormal, ⟂ c_true
    q0 = 0.1 * torch.randn(n_joints, generator=gen, dtype=f64)
    h = 2.0 / (steps - 1)
    Q_list, chi_list = [], []
    for _ in range(n_seq):
        chi = [-1.0 + 0.2 * float(torch.rand((), generator=gen, dtype=f64))]
        for _ in range(steps - 1):
            chi.append(chi[-1] + h * (1.0 + speed_variation * math.sin(math.pi * chi[-1])))
        chi_t = torch.tensor(chi, dtype=f64)
        waves = [(torch.cos if k % 2 == 0 else torch.sin)(math.pi * (k // 2 + 1) * chi_t) for k in range(n_joints - 1)]
        phi = amplitude * torch.stack(waves, dim=1)
        q = q0 + chi_t[:, None] * c_true / c_true.dot(c_true) + phi @ U.T
        Q_list.append(q + noise_std * torch.randn(q.shape, generator=gen, dtype=f64))
        chi_list.append(chi_t)
    return SyntheticGait(Q_list=Q_list, chi_list=chi_list, c_true=c_true, q0=q0)


def run_gpdm_bench(
    *,
    n_seq: int = 3,
    steps: int = 100,
    n_joints: int = 5,
    seed: int = 0,
    config: GPDMConfig = GPDMConfig(),
    threads: int | None = 1,
) -> dict[str, float]:
    """Fit a GPDM to :func:`synthetic_gait` data and time it.

    Args:
        n_seq, steps, n_joints, seed: the data (:func:`synthetic_gait`).
        config: the fit options.
        threads: torch intra-op threads during the fit (restored after); ``None`` leaves
            torch's setting.  The matrices are small (N = n_seq · steps), so 1 is fastest,
            and far faster than 2 when other processes share the cores.

    Returns:
        ``fit_seconds`` (wall clock), ``cos_c`` (|cos| between fitted c and c_true),
        ``corr_latent`` (|corr| of the MAP latents with χ), ``corr_projection``
        (|corr| of c·(q − q̄) with χ), ``objective``, ``peak_rss_mib``, the 1-minute
        load average before and after, and the sizes.
    """
    data = synthetic_gait(n_seq=n_seq, steps=steps, n_joints=n_joints, seed=seed)
    load_before = os.getloadavg()[0]
    with torch_threads(threads):
        t0 = time.perf_counter()
        model = fit_gpdm(data.Q_list, config=config)
        seconds = time.perf_counter() - t0
    chi = torch.cat(data.chi_list)
    c = model.c
    return {
        "n_seq": n_seq,
        "steps": steps,
        "n_joints": n_joints,
        "threads": threads if threads is not None else torch.get_num_threads(),
        "fit_seconds": seconds,
        "cos_c": float((c @ data.c_true).abs() / (c.norm() * data.c_true.norm())),
        "corr_latent": abs(compare_latents(torch.cat(model.latents), chi).corr),
        "corr_projection": abs(compare_latents(model.project(torch.cat(data.Q_list)), chi).corr),
        "objective": float(model.objective().total.detach()),
        "peak_rss_mib": peak_rss_mib(),
        "loadavg_before": load_before,
        "loadavg_after": os.getloadavg()[0],
    }


def main(argv: list[str] | None = None) -> int:
    """``python -m bemlearn.bench.gpdm_bench``: print the bench result as one JSON line."""
    parser = argparse.ArgumentParser(prog="python -m bemlearn.bench.gpdm_bench", description=__doc__.splitlines()[0])
    parser.add_argument("--n-seq", type=int, default=3)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--n-joints", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--optimizer", choices=["lbfgs", "adam"], default="lbfgs")
    parser.add_argument("--max-iter", type=int, default=GPDMConfig.max_iter)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads during the fit (default 1)")
    args = parser.parse_args(argv)
    if args.threads < 1:
        parser.error(f"--threads: expected a positive integer, got {args.threads}")
    config = GPDMConfig(optimizer=args.optimizer, max_iter=args.max_iter, seed=args.seed)
    result = run_gpdm_bench(
        n_seq=args.n_seq, steps=args.steps, n_joints=args.n_joints, seed=args.seed, config=config, threads=args.threads
    )
    print(json.dumps(result))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
