"""Small shims over MuJoCo Python API differences between 3.3 and 4.x.

* Dense mass matrix: ``mj_fullM(m, d, dst)`` (3.x late and 4.x, reads the sparse inertia from
  ``d``) versus ``mj_fullM(m, dst, d.qM)`` (older 3.x, where ``MjData.qM`` exists).
* Composite rigid body: ``mj_makeM`` (newer) versus ``mj_crb`` (older).
"""

from __future__ import annotations

import mujoco
import numpy as np

__all__ = ["full_mass_matrix", "make_mass_matrix"]


def make_mass_matrix(m: mujoco.MjModel, d: mujoco.MjData) -> None:
    """Fill the sparse inertia in ``d`` (needs ``mj_kinematics`` and ``mj_comPos`` first)."""
    if hasattr(mujoco, "mj_makeM"):
        mujoco.mj_makeM(m, d)
    else:  # pragma: no cover - older MuJoCo
        mujoco.mj_crb(m, d)


def full_mass_matrix(m: mujoco.MjModel, d: mujoco.MjData, out: np.ndarray) -> np.ndarray:
    """Write the dense ``(nv, nv)`` mass matrix into ``out`` and return it."""
    try:
        mujoco.mj_fullM(m, d, out)
    except TypeError:  # pragma: no cover - older MuJoCo: mj_fullM(m, dst, M)
        mujoco.mj_fullM(m, out, d.qM)
    return out
