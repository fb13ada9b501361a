"""Which robot a run is about: the config's ``robot:`` (registry name or MJCF path), or none.

A run with ``robot:`` records it as a :class:`~bemlearn.robots.RobotRef` (MJCF path and
sha256, registry name if any); its model-based BEM (eq. 9) is the ground truth of the
evaluation.  A model-free run (``data:`` and no ``robot:``) learns from the data alone: the
joints and the unactuated joint come from the data file, nothing is compared with a model
unless the config names one under ``model:`` (an MJCF used for the comparison only).
"""

from __future__ import annotations

from bemlearn.robots import RobotRef, resolve_robot

__all__ = ["run_robot"]


def run_robot(config, loaded=None):
    """``(robot, ref, truth_robot)`` of a pipeline config.

    ``robot`` is the robot that collects/simulates (``None`` for a model-free run), ``ref``
    what the run records, ``truth_robot`` the model whose BEM the learned one is compared
    with (the robot itself, the ``model:`` of a model-free run, or ``None``).  ``loaded``:
    ``(robot, ref)`` of ``config.robot`` when the caller has resolved it already
    (:func:`~bemlearn.robots.resolve_robot`; a run loads its robot once).
    """
    if config.robot is not None:
        robot, ref = loaded if loaded is not None else resolve_robot(config.robot, coordinates=config.coordinates)
        return robot, ref, robot
    truth = resolve_robot(config.model, coordinates=config.coordinates)[0] if config.model else None
    return None, RobotRef(name="data", mjcf=None, sha256=None, registry=None), truth

