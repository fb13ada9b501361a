"""The bikebot application: an autonomous bicycle, steering δ and rear-wheel speed driven, roll φ free.

Its first layer is the *model roll BEM*: the roll at which the roll acceleration vanishes for a given
speed and steer, from MuJoCo's constrained dynamics with the wheels' hard rolling constraint
(:mod:`bemlearn.apps.bikebot.bem`), checked against the steady-turn Newton–Euler balance about the ground
line (:mod:`bemlearn.apps.bikebot.steady_turn`); the MJCF is generated from the benchmark bicycle's
parameters (:mod:`bemlearn.apps.bikebot.model`, ``assets/bikebot.xml``).  The second layer rides it in
MuJoCo's soft-contact simulation (:mod:`bemlearn.apps.bikebot.ride`: a rig's sensors, a steer-into-the-fall
balance law, a speed loop) and learns its roll BEM from excitation rides with the core's derivative estimators
and GP (:mod:`bemlearn.apps.bikebot.learn`), and follows paths with the EIC and a roll BEM
(:mod:`bemlearn.apps.bikebot.eic`).  It registers the commands ``bemlearn bench bikebot-bem``,
``bemlearn bench bikebot-learned`` and ``bemlearn bench bikebot-eic``.  The core's pipeline still refuses the robot (steered, leaning wheels:
nonholonomic rolling).
"""

from __future__ import annotations

from bemlearn.applications import Application

__all__ = ["APPLICATION"]


def _bench(sub) -> None:
    from bemlearn.apps.bikebot.bench import add_bench
    from bemlearn.apps.bikebot.eic_bench import add_eic_bench
    from bemlearn.apps.bikebot.learn_bench import add_learned_bench

    add_bench(sub)
    add_learned_bench(sub)
    add_eic_bench(sub)


APPLICATION = Application(
    name="bikebot",
    description="autonomous bicycle (bikebot): model roll BEM from the hard rolling constraint, learned roll BEM",
    add_bench=_bench,
)
