"""The bikebot application: an autonomous bicycle, steering δ and rear-wheel speed driven, roll φ free.

Its first layer is the *model roll BEM*: the roll at which the roll acceleration vanishes for a given
speed and steer, from MuJoCo's constrained dynamics with the wheels' hard rolling constraint
(:mod:`bemlearn.apps.bikebot.bem`), checked against the steady-turn Newton–Euler balance about the ground
line (:mod:`bemlearn.apps.bikebot.steady_turn`); the MJCF is generated from the benchmark bicycle's
parameters (:mod:`bemlearn.apps.bikebot.model`, ``assets/bikebot.xml``).  It registers the command
``bemlearn bench bikebot-bem``.  The core's pipeline still refuses the robot (steered, leaning wheels:
nonholonomic rolling); excitation, learning and the EIC are not written yet.
"""

from __future__ import annotations

from bemlearn.applications import Application

__all__ = ["APPLICATION"]


def _bench(sub) -> None:
    from bemlearn.apps.bikebot.bench import add_bench

    add_bench(sub)


APPLICATION = Application(
    name="bikebot",
    description="autonomous bicycle (bikebot): model roll BEM from the hard rolling constraint",
    add_bench=_bench,
)
