"""Units that follow the joint: a hinge's coordinate is an angle, a slide's a length.

    hinge:  q rad,  q̇ rad/s,  q̈ rad/s^2,  generalized force N·m
    slide:  q m,    q̇ m/s,    q̈ m/s^2,    generalized force N

Every number bemlearn prints or stores for a coordinate carries the unit of its joint's kind:
data checks, trajectory metadata (``meta.joint_kinds``, default every joint a hinge), GP input
columns (``qdd_<j>``, ``qd_<j>``, ``q_<j>``), the predictor contract, reports and CLI output.
Stored unit strings are ASCII (``rad/s^2``).  Encoder resolution is given in the joint's own
units too: counts per revolution for a hinge, metres per count for a slide.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from bemlearn.errors import ArgumentError

__all__ = ["JOINT_KINDS", "joint_unit", "q_unit_label", "gp_input_units", "generalized_force_unit", "resolution_text"]

#: Valid joint kinds and their (q, q̇, q̈) units.
JOINT_KINDS: dict[str, tuple[str, str, str]] = {
    "hinge": ("rad", "rad/s", "rad/s^2"),
    "slide": ("m", "m/s", "m/s^2"),
}

_FORCE = {"hinge": "N·m", "slide": "N"}


def _check(kind: str) -> str:
    if kind not in JOINT_KINDS:
        raise ArgumentError(f"joint kind {kind!r}: expected one of {sorted(JOINT_KINDS)}")
    return kind


def joint_unit(kind: str, order: int = 0) -> str:
    """Unit of the ``order``-th time derivative (0, 1, 2) of a ``kind`` joint's coordinate."""
    if order not in (0, 1, 2):
        raise ArgumentError(f"derivative order {order!r}: expected 0, 1 or 2")
    return JOINT_KINDS[_check(kind)][order]


def q_unit_label(kinds: Sequence[str], order: int = 0) -> str:
    """The ``meta.units`` entry of q (order 0), qd (1) or qdd (2): one unit if all joints share it,
    else the per-joint units joined by ``|`` in joint order (e.g. ``"m|rad"`` for a cart-pole)."""
    units = [joint_unit(k, order) for k in kinds]
    return units[0] if len(set(units)) == 1 else "|".join(units)


def gp_input_units(input_names: Sequence[str], joint_names: Sequence[str], kinds: Sequence[str]) -> dict[str, str]:
    """Unit of each GP input column (``qdd_<j>``, ``qd_<j>``, ``q_<j>``, eq. 11) from its joint's kind."""
    kind_of = dict(zip(joint_names, kinds))
    out = {}
    for name in input_names:
        prefix, _, joint = name.partition("_")
        order = {"q": 0, "qd": 1, "qdd": 2}.get(prefix)
        if order is None or joint not in kind_of:
            raise ArgumentError(f"GP input {name!r}: expected qdd_<joint>, qd_<joint> or q_<joint> of {list(joint_names)}")
        out[name] = joint_unit(kind_of[joint], order)
    return out


def generalized_force_unit(kind: str) -> str:
    """Unit of the generalized force on a joint of ``kind``: N·m (hinge) or N (slide)."""
    return _FORCE[_check(kind)]


def resolution_text(kind: str, step: float) -> str:
    """A quantization step in the joint's own terms: ``"4096 counts/rev"`` or ``"1e-05 m/count"``."""
    if _check(kind) == "hinge":
        counts = 2 * math.pi / step
        return f"{counts:.0f} counts/rev" if abs(counts - round(counts)) < 1e-6 * counts else f"{step:.3g} rad/count"
    return f"{step:.3g} m/count"
