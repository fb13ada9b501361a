"""Regenerate the shipped MJCF assets from their parameter dataclasses.

Run ``python -m bemlearn.robots.write_assets`` after changing parameters; a test checks
the shipped files equal the generators' output.
"""

from __future__ import annotations

from bemlearn.robots.biped import biped_pinned_mjcf, biped_planar_mjcf
from bemlearn.robots.furuta import furuta_mjcf
from bemlearn.robots.registry import ASSETS

__all__ = ["GENERATED_ASSETS", "write_assets"]

GENERATED_ASSETS = {
    "furuta.xml": furuta_mjcf,
    "biped_pinned.xml": biped_pinned_mjcf,
    "biped_planar.xml": biped_planar_mjcf,
}


def write_assets() -> None:
    for name, make in GENERATED_ASSETS.items():
        (ASSETS / name).write_text(make())


if __name__ == "__main__":
    write_assets()
