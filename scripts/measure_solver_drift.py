"""How far GPyTorch's default solver moves the exact GP's posterior mean above 800 points.

    python scripts/measure_solver_drift.py

Conditions the exact GP of ``tests/test_gp_parity.py`` (5 inputs, noise 1e-3, fixed
hyperparameters) on N = 800 and 801 points and prints max |μ_default − μ_dense| over its 300
test points: μ_default is GPyTorch's prediction under its default settings (Cholesky up to
``max_cholesky_size`` = 800, conjugate gradients above), μ_dense eq. (12) with
``torch.linalg.solve``.  The figure is quoted in docs/design.md ("Solver policy").
"""

from __future__ import annotations

import platform
import sys
from pathlib import Path

import gpytorch
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_gp_parity import _dense_posterior, _problem


def main() -> None:
    torch.set_num_threads(1)
    for n in (800, 801):
        model, lik, xs = _problem(n)
        ref, _ = _dense_posterior(model, xs)
        model.eval()
        lik.eval()
        with torch.no_grad():
            mean = model(xs).mean
        print(f"N = {n}: max |μ_default − μ_dense| = {float((mean - ref).abs().max()):.3g} "
              f"(max |μ_dense| = {float(ref.abs().max()):.3g})")
    print(f"torch {torch.__version__}, gpytorch {gpytorch.__version__}, {platform.machine()}")


if __name__ == "__main__":
    main()
