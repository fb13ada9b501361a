"""The biped application's MJCF assets: the pinned-stance model (a :class:`~bemlearn.robots.Robot`)
and the floating planar walker (a simulation model, not a Robot: its torso has three
unactuated coordinates).

Run ``python -m bemlearn.apps.biped.assets`` after changing :class:`BipedParameters`;
a test checks the shipped files equal the generators' output.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import mujoco

__all__ = ["ASSETS", "PINNED_XML", "PLANAR_XML", "planar_model", "generated_assets", "write_assets"]

ASSETS = Path(__file__).parent / "assets"
PINNED_XML = ASSETS / "biped_pinned.xml"
PLANAR_XML = ASSETS / "biped_planar.xml"


def planar_model() -> mujoco.MjModel:
    """The floating planar walker (``assets/biped_planar.xml``), as simulated by :mod:`bemlearn.apps.biped.walker`."""
    import mujoco

    return mujoco.MjModel.from_xml_path(str(PLANAR_XML))


def generated_assets() -> dict[str, str]:
    """File name → MJCF text as generated from the parameters."""
    from bemlearn.apps.biped.model import biped_pinned_mjcf, biped_planar_mjcf

    return {"biped_pinned.xml": biped_pinned_mjcf(), "biped_planar.xml": biped_planar_mjcf()}


def write_assets() -> None:
    for name, text in generated_assets().items():
        (ASSETS / name).write_text(text)


if __name__ == "__main__":
    write_assets()
