"""The bikebot application's MJCF asset: its path and its generator.

Run ``python -m bemlearn.apps.bikebot.assets`` after changing :class:`~bemlearn.apps.bikebot.model.BikeParameters`;
a test checks the shipped file equals the generator's output.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["ASSETS", "BIKEBOT_XML", "generated_assets", "write_assets"]

ASSETS = Path(__file__).parent / "assets"
BIKEBOT_XML = ASSETS / "bikebot.xml"


def generated_assets() -> dict[str, str]:
    """File name → MJCF text as generated from the parameters."""
    from bemlearn.apps.bikebot.model import bikebot_mjcf

    return {"bikebot.xml": bikebot_mjcf()}


def write_assets() -> None:
    for name, text in generated_assets().items():
        (ASSETS / name).write_text(text)


if __name__ == "__main__":
    write_assets()
