"""Configuration of GP training (kind, optimizer, inducing points, minibatches)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from bemlearn._lazy import lazy_module
from bemlearn.config import Limit, config_limits
from bemlearn.errors import ConfigError

if TYPE_CHECKING:
    import torch
else:
    torch = lazy_module("torch")

__all__ = ["GPConfig"]

#: What ``torch.device`` accepts: a device type, optionally ``:index`` (checked without importing
#: torch, so that reading a config stays fast; ``tests/test_config_validation.py`` compares with torch).
DEVICE_PATTERN = re.compile(r"(cpu|cuda|ipu|xpu|mkldnn|opengl|opencl|ideep|hip|ve|fpga|maia|xla|lazy|vulkan|mps|meta|hpu|mtia"
                            r"|privateuseone)(:(0|[1-9][0-9]*))?")


@dataclass(frozen=True)
class GPConfig:
    """How to build and train one BEM GP; parse with ``bemlearn.config.from_dict(GPConfig, mapping)``.

    Attributes:
        kind: ``"exact"``, ``"sgpr"`` or ``"svgp"`` (see ``bemlearn.models.GP_KINDS``).
        mean: the GP's prior mean: ``"zero"`` (eq. 11 as written), ``"linear"``, a least-squares plane in the
            inputs with the kernel on its residual (eq. L1 of ``bemlearn.fitting.linear_mean``: the BEM's
            linearisation at the upright), or ``"auto"``: both are fitted and the data choose by the marginal
            likelihood with the plane's coefficients priced (eq. L2).  The plane extrapolates the mean better
            beyond the excited states, but its band there is the residual's, often too narrow (docs/family.md);
            the zero mean's band widens.  Applied by the training stage (``bemlearn.pipeline.fit_bem_gp``);
            ``train_gp`` fits the labels it is given.  A run with ``robot:`` derives it when the config does not give
            it: ``auto`` where the excitation moves each actuated direction on its own (m ≥ 2, ``collect.excursion``),
            else ``zero`` (``bemlearn config show``; ``bemlearn.pipeline.derived_defaults.PRIOR_MEAN_NOTE``).
        n_inducing: number of inducing points M (sgpr, svgp).
        inducing_init: ``"kmeans++"`` (D²-weighted seeding) or ``"random"`` subset of the inputs.
        learn_inducing: optimize the inducing inputs Z.
        init_subset: size of the random subset on which a small exact GP is fitted first to
            initialize the sgpr/svgp hyperparameters (0: initialize from data statistics only).
        fit_subset: sgpr only: optimize θ and Z on this many random points, then condition
            on all N (0: optimize on all N).
        optimizer: ``"lbfgs"`` or ``"adam"`` for exact and sgpr (svgp always uses natural gradients
            for q(v) and Adam for θ, Z).
        max_iter: L-BFGS iterations (≤ 1.5 · max_iter loss evaluations) or Adam steps; ``None``:
            300 for exact (a bound, not a cost: fits stop when they converge), 30 for sgpr (each sgpr
            evaluation costs O(fit_subset · M²)).
        lr: learning rate; ``None`` picks the default of the optimizer: 1.0 for L-BFGS (initial
            step), 0.05 for Adam on exact/sgpr, 0.003 for the svgp hyperparameters.
        ngd_lr: svgp natural-gradient step size for q(v).
        tol: L-BFGS stops when the loss changes by less than ``tol`` (nats per point) between iterations.
        batch_size: svgp minibatch size.
        refresh_q: svgp: set q(v) to its optimum for the final θ, Z after training.
        epochs: svgp passes over the data.
        min_noise: lower bound of σ_0² (normalized output units squared).
        jitter: first Cholesky jitter j₀ (and the fixed K_ZZ jitter of sgpr/svgp).
        seed: seed of every random choice (subsets, k-means++, minibatch order).
        device: torch device string, e.g. ``"cpu"`` or ``"cuda"``.
        dtype: ``"float64"`` (default; GP work) or ``"float32"``.
    """

    kind: Literal["exact", "sgpr", "svgp"] = "exact"
    mean: Literal["zero", "linear", "auto"] = "zero"
    n_inducing: int = 256
    inducing_init: Literal["kmeans++", "random"] = "kmeans++"
    learn_inducing: bool = True
    init_subset: int = 500
    fit_subset: int = 10_000
    optimizer: Literal["lbfgs", "adam"] = "lbfgs"
    max_iter: int | None = None
    lr: float | None = None
    ngd_lr: float = 0.01
    tol: float = 1e-9
    batch_size: int = 4096
    epochs: int = 10
    refresh_q: bool = True
    min_noise: float = 1e-6
    jitter: float = 1e-8
    seed: int = 0
    device: str = "cpu"
    dtype: Literal["float64", "float32"] = "float64"

    def __post_init__(self) -> None:
        for name in ("n_inducing", "max_iter", "batch_size", "epochs"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ConfigError(f"{name}: expected a positive integer, got {getattr(self, name)}")
        for name in ("init_subset", "fit_subset"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name}: expected a non-negative integer, got {getattr(self, name)}")
        if self.lr is not None and not self.lr > 0.0:
            raise ConfigError(f"lr: expected a positive number, got {self.lr}")
        for name in ("ngd_lr", "min_noise", "jitter"):
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"{name}: expected a positive number, got {getattr(self, name)}")
        if self.tol < 0.0:
            raise ConfigError(f"tol: expected a non-negative number, got {self.tol}")
        if not DEVICE_PATTERN.fullmatch(self.device):
            raise ConfigError(f"device: not a torch device string (cpu, cuda, cuda:1, mps, ...): {self.device!r}")

    @property
    def torch_dtype(self) -> torch.dtype:
        """The torch dtype named by :attr:`dtype`."""
        return {"float64": torch.float64, "float32": torch.float32}[self.dtype]


# (the lower bounds of the counts and step sizes are checked by __post_init__)
config_limits(GPConfig, n_inducing=Limit(le=10**6), init_subset=Limit(le=10**7), fit_subset=Limit(le=10**8),
              max_iter=Limit(le=10**7), tol=Limit(ge=0), batch_size=Limit(le=10**8), epochs=Limit(le=10**6), seed=Limit(ge=0))
