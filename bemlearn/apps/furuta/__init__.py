"""The Furuta application: the Quanser rotary pendulum of the paper's Section IV-A.

Registers the robots ``furuta`` (the MuJoCo model, ``assets/furuta.xml``, Quanser motor in
volts as a MuJoCo affine actuator), ``furuta-analytic`` (its closed-form rigid-body model,
:class:`~bemlearn.apps.furuta.model.AnalyticFuruta`) and ``furuta-paper`` (the rows printed
in the paper), and the command ``bemlearn robot furuta-variants``.  Everything else the
Furuta does (collect, train, export, evaluate, closed loop) is the core's generic pipeline:
``bemlearn run configs/furuta.yaml``.
"""

from __future__ import annotations

from bemlearn.applications import Application

__all__ = ["APPLICATION"]


def _mujoco():
    from bemlearn.apps.furuta.assets import FURUTA_XML
    from bemlearn.robots.mujoco_robot import MujocoRobot

    return MujocoRobot.from_xml(FURUTA_XML, name="furuta")


def _analytic(variant: str):
    def make():
        from bemlearn.apps.furuta.model import AnalyticFuruta

        return AnalyticFuruta(variant=variant)

    return make


def _robot_commands(rs) -> None:
    from bemlearn.apps.furuta.variants_cmd import add_robot_commands

    add_robot_commands(rs)


APPLICATION = Application(
    name="furuta",
    description="Quanser rotary (Furuta) pendulum, paper Section IV-A",
    robots={"furuta": _mujoco, "furuta-analytic": _analytic("rigid"), "furuta-paper": _analytic("paper")},
    add_robot_commands=_robot_commands,
)
