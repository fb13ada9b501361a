"""Registry of the GP kinds by name: ``"exact"``, ``"sgpr"``, ``"svgp"``."""

from __future__ import annotations

import torch

from bemlearn.errors import ArgumentError, ConfigError
from bemlearn.models.exact_gp import ExactBEMGP
from bemlearn.models.sgpr import SGPRBEMGP
from bemlearn.models.svgp import SVGPBEMGP

__all__ = ["GP_KINDS", "BEMGP", "gp_class", "gp_kind_of"]

#: Model class of each GP kind.
GP_KINDS: dict[str, type[torch.nn.Module]] = {"exact": ExactBEMGP, "sgpr": SGPRBEMGP, "svgp": SVGPBEMGP}

BEMGP = ExactBEMGP | SGPRBEMGP | SVGPBEMGP


def gp_class(kind: str) -> type[torch.nn.Module]:
    """The model class registered under ``kind``.

    Raises:
        ConfigError: (a ValueError) unknown kind; the message lists the valid names.
    """
    try:
        return GP_KINDS[kind]
    except (KeyError, TypeError):
        raise ConfigError(f"GP kind: unknown {kind!r}; valid kinds are {sorted(GP_KINDS)}") from None


def gp_kind_of(model: object) -> str:
    """The registered kind name of a model instance.

    Raises:
        ArgumentError: (a TypeError) ``model`` is none of the registered classes.
    """
    for name, cls in GP_KINDS.items():
        if isinstance(model, cls):
            return name
    raise ArgumentError(f"model: expected one of {[c.__name__ for c in GP_KINDS.values()]}, got {type(model).__name__}")
