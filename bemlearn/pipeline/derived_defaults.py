"""Adapter: the pipeline keys the robot's model determines (filled in by the derive stage)."""

from __future__ import annotations

__all__ = ["derive_pipeline_values"]


def derive_pipeline_values(robot, config) -> dict:
    """``{dotted key: (value, how it was derived)}`` for every derivable key (see docs/config.md)."""
    return {}
