"""The registry of the GP kinds: the one place where a kind's name becomes its class.

A GP kind is its model class.  The name (``train.kind`` of a config, ``kind`` of a checkpoint or
:class:`~bemlearn.models.predictor_state.PredictorState`) is turned into the class here, by
:func:`gp_class`, and nowhere else; everything else asks the class (BoTorch's pattern: the
model carries ``posterior()``, the fitting functions dispatch on the model's type).  Each
class carries the math of its kind, with one meaning per method on every kind:

* ``kind`` (its registered name) and ``sparse``: whether the posterior lives on M inducing
  inputs Z with S held factored as L⁻ᵀ C L⁻¹ (sgpr, svgp), or on the N training inputs with
  S = (K_XX + σ_0² I)⁻¹ solved through its Cholesky factor (exact);
* ``forward(x)``: the prior N(0, K_xx) of eq. (11), as GPyTorch's models define it;
* ``posterior(x)``: the latent posterior of f at x (eq. 12, or its sparse counterpart), in eval mode;
* ``posterior_weights()`` and ``variance_factor()``: the frozen form μ = k_Zᵀ α,
  Σ = σ_f² − k_Zᵀ S k_Z (:mod:`bemlearn.models.freeze`).

How a kind is built and fitted belongs to the fitting layer (:mod:`bemlearn.fitting.kinds`),
keyed by these classes.
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol, cast

import gpytorch
import torch

from bemlearn.errors import ArgumentError, ConfigError
from bemlearn.models.exact_gp import ExactBEMGP
from bemlearn.models.sgpr import SGPRBEMGP
from bemlearn.models.svgp import SVGPBEMGP

__all__ = ["GP_KINDS", "BEMGP", "gp_class", "gp_kind_of", "as_gp"]


class BEMGP(Protocol):
    """What every GP kind's model class provides (module docstring)."""

    kind: ClassVar[str]
    sparse: ClassVar[bool]
    covar_module: Any

    @property
    def dim(self) -> int:
        """Input dimension d."""
        ...

    def forward(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
        """Prior N(0, K_xx) at ``x: (B, d)`` normalized inputs."""
        ...

    def posterior(self, x: torch.Tensor) -> gpytorch.distributions.MultivariateNormal:
        """Latent posterior of f at ``x: (B, d)`` normalized inputs."""
        ...

    def posterior_weights(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(M, d)`` Z, ``(M,)`` α, ``(M, M)`` S of the frozen posterior, normalized units."""
        ...

    def variance_factor(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """L, C of a sparse S = L⁻ᵀ C L⁻¹, or ``None`` (exact)."""
        ...


#: Model class of each GP kind, by its registered name.
GP_KINDS: dict[str, type[BEMGP]] = {cls.kind: cls for cls in (ExactBEMGP, SGPRBEMGP, SVGPBEMGP)}


def gp_class(kind: str) -> type[BEMGP]:
    """The model class registered under ``kind``.

    Raises:
        ConfigError: (a ValueError) unknown kind; the message lists the valid names.
    """
    try:
        return GP_KINDS[kind]
    except (KeyError, TypeError):
        raise ConfigError(f"GP kind: unknown {kind!r}; valid kinds are {sorted(GP_KINDS)}") from None


def as_gp(model: object) -> BEMGP:
    """``model`` as a GP of a registered kind.

    Raises:
        ArgumentError: (a TypeError) ``model`` is an instance of none of the registered classes.
    """
    if not isinstance(model, tuple(cast(Any, GP_KINDS.values()))):
        raise ArgumentError(f"model: expected one of {[c.__name__ for c in GP_KINDS.values()]}, got {type(model).__name__}")
    return cast(BEMGP, model)


def gp_kind_of(model: object) -> str:
    """The registered kind name of a model instance.

    Raises:
        ArgumentError: (a TypeError) ``model`` is none of the registered classes.
    """
    return as_gp(model).kind
