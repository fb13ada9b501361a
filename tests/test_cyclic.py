"""Cyclic coordinates (bemlearn.robots.cyclic): positions the dynamics do not depend on, from the physics.

Expected by construction of each model: a wheel's angle (a symmetric wheel, no springs) and a cart's
position on a level rail are cyclic; a pendulum under gravity and the links of a double pendulum are not;
a joint spring makes an otherwise cyclic wheel angle non-cyclic.
"""

from __future__ import annotations

from pathlib import Path

from bemlearn.robots import load
from bemlearn.robots.cyclic import cyclic_coordinates

ROBOTS = Path(__file__).resolve().parent / "robots"


def test_wheels_and_carts_are_cyclic_pendulums_are_not():
    assert cyclic_coordinates(load(ROBOTS / "wheel_pendulum.xml")) == (True, False)     # (spin, pitch)
    assert cyclic_coordinates(load(ROBOTS / "reaction_wheel.xml")) == (False, True)     # (pendulum, wheel)
    assert cyclic_coordinates(load(ROBOTS / "cartpole.xml")) == (True, False)           # (slider, hinge)
    assert cyclic_coordinates(load(ROBOTS / "acrobot.xml")) == (False, False)


def test_a_spring_on_the_wheel_makes_it_not_cyclic(tmp_path):
    path = tmp_path / "sprung.xml"
    path.write_text((ROBOTS / "wheel_pendulum.xml").read_text().replace('damping="0.01"', 'damping="0.01" stiffness="0.5"'))
    assert cyclic_coordinates(load(path)) == (False, False)
