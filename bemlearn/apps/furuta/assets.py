"""The Furuta application's MJCF asset: its path and its generator.

Run ``python -m bemlearn.apps.furuta.assets`` after changing :class:`FurutaParameters`;
a test checks the shipped file equals the generator's output.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["ASSETS", "FURUTA_XML", "generated_assets", "write_assets"]

ASSETS = Path(__file__).parent / "assets"
FURUTA_XML = ASSETS / "furuta.xml"


def generated_assets() -> dict[str, str]:
    """File name → MJCF text as generated from the parameters."""
    from bemlearn.apps.furuta.model import furuta_mjcf

    return {"furuta.xml": furuta_mjcf()}


def write_assets() -> None:
    for name, text in generated_assets().items():
        (ASSETS / name).write_text(text)


if __name__ == "__main__":
    write_assets()
