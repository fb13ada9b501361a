"""``bemlearn bench predict [CHECKPOINT]``: latency / throughput / parity of the BEM predictor.

Provisional home of the ``bench`` command (only the ``predict`` benchmark so far); see
:mod:`bemlearn.bench.predict_bench` for what is measured.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bemlearn.bench.predict_bench import format_predict_bench, run_predict_bench

__all__ = ["add_parser", "run_predict"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("bench", help="benchmarks", description="Benchmarks of bemlearn components.")
    sub = parser.add_subparsers(dest="bench", metavar="BENCH", required=True)
    p = sub.add_parser(
        "predict",
        help="latency, throughput and GPyTorch parity of the exported BEM predictor",
        description="Time the exported BEM predictor (TorchScript and torch.export) against NumPy and "
        "GPyTorch, single queries (B = 1) and a 1e5 batch.  Without CHECKPOINT a synthetic 500-point "
        "exact GP (d = 5, m = 1) is used.  Other load on the machine changes the numbers; the "
        "load average is printed.",
    )
    p.add_argument("checkpoint", metavar="CHECKPOINT", type=Path, nargs="?", default=None, help="run directory or checkpoint.pt")
    p.add_argument("--n-train", type=int, default=500, help="points of the synthetic model (default 500)")
    p.add_argument("--repeats", type=int, default=20000, help="timed calls per single-query case (default 20000)")
    p.add_argument("--gpytorch-repeats", type=int, default=200, help="timed GPyTorch calls (default 200)")
    p.add_argument("--batch", type=int, default=100_000, help="queries in the throughput case (default 1e5)")
    p.add_argument("--threads", type=int, default=1, help="torch/BLAS threads (default 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-pt2", action="store_true", help="skip the torch.export artifact")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_predict)


def run_predict(args: argparse.Namespace) -> int:
    for name in ("n_train", "repeats", "gpytorch_repeats", "batch", "threads"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')}: expected a positive integer, got {getattr(args, name)}")
    result = run_predict_bench(
        checkpoint=args.checkpoint,
        n_train=args.n_train,
        seed=args.seed,
        repeats=args.repeats,
        warmup=min(2000, args.repeats),
        gpytorch_repeats=args.gpytorch_repeats,
        batch=args.batch,
        threads=args.threads,
        pt2=not args.no_pt2,
        progress=not args.no_progress,
    )
    print(format_predict_bench(result))
    return 0
