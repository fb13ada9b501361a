"""Units that follow the joint: hinge → rad, rad/s, rad/s²; slide → m, m/s, m/s².

Every number bemlearn prints or stores for a coordinate carries the unit of its joint's kind:
data checks, trajectory metadata, GP input columns (``qdd_<j>``, ``qd_<j>``, ``q_<j>``), the
predictor contract, reports and CLI output.  Encoder resolution is given in the joint's own
units too: counts per revolution for a hinge, metres per count for a slide.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

__all__ = ["JOINT_KINDS", "coordinate_units", "column_unit", "column_units", "resolution_text", "generalized_force_unit"]

#: The joint kinds bemlearn robots may have.
JOINT_KINDS = ("hinge", "slide")

_UNITS = {"hinge": ("rad", "rad/s", "rad/s²"), "slide": ("m", "m/s", "m/s²")}
_FORCE = {"hinge": "N·m", "slide": "N"}


def _check(kind: str, where: str) -> str:
    if kind not in _UNITS:
        raise ValueError(f"{where}: unknown joint kind {kind!r}; expected one of {list(JOINT_KINDS)}")
    return kind


def coordinate_units(kind: str) -> tuple[str, str, str]:
    """``(q, q̇, q̈)`` units of a joint of ``kind`` (``"hinge"`` or ``"slide"``)."""
    return _UNITS[_check(kind, "coordinate_units")]


def generalized_force_unit(kind: str) -> str:
    """Unit of the generalized force on a joint of ``kind``: N·m (hinge) or N (slide)."""
    return _FORCE[_check(kind, "generalized_force_unit")]


def column_unit(column: str, kinds: Mapping[str, str]) -> str:
    """Unit of a GP/trajectory column ``q_<j>``, ``qd_<j>`` or ``qdd_<j>`` given ``kinds[j]``."""
    for prefix, order in (("qdd_", 2), ("qd_", 1), ("q_", 0)):
        if column.startswith(prefix):
            joint = column[len(prefix):]
            if joint not in kinds:
                raise ValueError(f"column {column!r}: joint {joint!r} has no known kind (joints: {sorted(kinds)})")
            return coordinate_units(kinds[joint])[order]
    raise ValueError(f"column {column!r}: expected q_<joint>, qd_<joint> or qdd_<joint>")


def column_units(columns: Sequence[str], kinds: Mapping[str, str]) -> dict[str, str]:
    """``{column: unit}`` for every column (see :func:`column_unit`)."""
    return {c: column_unit(c, kinds) for c in columns}


def resolution_text(kind: str, step: float) -> str:
    """A quantization step in the joint's own terms: ``"4096 counts/rev"`` or ``"1e-05 m/count"``."""
    import math

    if _check(kind, "resolution_text") == "hinge":
        counts = 2 * math.pi / step
        return f"{counts:.0f} counts/rev" if abs(counts - round(counts)) < 1e-6 * counts else f"{step:.3g} rad/count"
    return f"{step:.3g} m/count"
