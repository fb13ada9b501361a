"""The GP input of eq. (11) built from joint angles and their derivatives.

For n joints with unactuated q_u and actuated q_a ∈ R^m (m = n − 1, robot joint order),

    x = [q̈_aᵀ, q̇_aᵀ, q_aᵀ, q̈_u, q̇_u]ᵀ ∈ R^(3n−1),     y = q_u          (eq. 11)

with columns named ``qdd_<a>…, qd_<a>…, q_<a>…, qdd_<u>, qd_<u>`` (Furuta:
``qdd_theta, qd_theta, q_theta, qdd_alpha, qd_alpha``).  The BEM query of eq. (14) is
the same x with q̈_u = q̇_u = 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from bemlearn._lazy import lazy_module
from bemlearn.errors import ArgumentError

if TYPE_CHECKING:
    import torch
else:
    torch = lazy_module("torch")

__all__ = ["gp_input_names", "gp_output_name", "gp_inputs"]

ArrayT = TypeVar("ArrayT", np.ndarray, "torch.Tensor")


def gp_input_names(joint_names: Sequence[str], unactuated: str) -> tuple[str, ...]:
    """The 3n − 1 column names of x (eq. 11) for ``joint_names`` with unactuated joint ``unactuated``."""
    if unactuated not in joint_names:
        raise ArgumentError(f"unactuated joint {unactuated!r} is not one of {list(joint_names)}")
    act = [j for j in joint_names if j != unactuated]
    return (
        *(f"qdd_{j}" for j in act),
        *(f"qd_{j}" for j in act),
        *(f"q_{j}" for j in act),
        f"qdd_{unactuated}",
        f"qd_{unactuated}",
    )


def gp_output_name(unactuated: str) -> str:
    """The name of y = q_u: ``q_<unactuated>``."""
    return f"q_{unactuated}"


def gp_inputs(q: ArrayT, qd: ArrayT, qdd: ArrayT, *, unactuated_index: int) -> ArrayT:
    """x = [q̈_a, q̇_a, q_a, q̈_u, q̇_u] (eq. 11) for given angles and derivatives.

    Args:
        q: (..., n) joint coordinates, rad (m for slides), robot joint order (numpy array or torch tensor).
        qd: (..., n) joint velocities, rad/s (m/s for slides).
        qdd: (..., n) joint accelerations, rad/s² (m/s² for slides).
        unactuated_index: column of q_u (``TrajectoryMeta.unactuated_index``).

    Returns:
        x: (..., 3n − 1), same type, dtype and device as ``q``; columns as in
        :func:`gp_input_names` (units rad/s², rad/s, rad, rad/s², rad/s; m/s², m/s, m for slides).
    """
    if not (q.shape == qd.shape == qdd.shape) or q.ndim < 1:
        raise ArgumentError(
            "gp_inputs: q, qd, qdd must share one shape (..., n), got "
            f"{tuple(q.shape)}, {tuple(qd.shape)}, {tuple(qdd.shape)}"
        )
    n = q.shape[-1]
    if not -n <= unactuated_index < n or n < 2:
        raise ArgumentError(f"gp_inputs: unactuated_index {unactuated_index} out of range for n = {n} joints (n >= 2)")
    u = unactuated_index % n
    act = [i for i in range(n) if i != u]
    parts = [qdd[..., act], qd[..., act], q[..., act], qdd[..., u:u + 1], qd[..., u:u + 1]]
    if isinstance(q, torch.Tensor):
        return torch.cat(parts, dim=-1)
    return np.concatenate(parts, axis=-1)
