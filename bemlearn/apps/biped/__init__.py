"""The biped application: the 5-link planar biped of the paper's Section IV-B.

Registers the robot ``biped`` (the pinned-stance model, ``assets/biped_pinned.xml``, torso
pitch q1 unactuated), the commands ``bemlearn walk`` and ``bemlearn gpdm``, the benches
``bemlearn bench biped-bem`` and ``bemlearn bench walks``, the sweep stages ``biped-bem`` and ``run``
(:mod:`bemlearn.apps.biped.sweep_stage`), and runs configs whose top-level
key is ``application: biped`` (``bemlearn run configs/biped.yaml``: walking data, the torso
BEM learned with the core's train → export stage, walking with it in the loop, GPDMs of the
robot's and the human gait, Fig. 4/5 and the report).
"""

from __future__ import annotations

from pathlib import Path

from bemlearn.applications import Application
from bemlearn.errors import ArgumentError

__all__ = ["APPLICATION"]


def _pinned():
    from bemlearn.apps.biped.assets import PINNED_XML
    from bemlearn.robots.mujoco_robot import MujocoRobot

    return MujocoRobot.from_xml(PINNED_XML, name="biped")


def _cli(sub) -> None:
    from bemlearn.apps.biped import gpdm_cmd, walk_cmd

    walk_cmd.add_parser(sub)
    gpdm_cmd.add_parser(sub)


def _bench(sub) -> None:
    from bemlearn.apps.biped.bench_cmd import add_bench

    add_bench(sub)


def _bem_stage():
    from bemlearn.apps.biped.sweep_stage import biped_bem_stage

    return biped_bem_stage()


def _run_stage():
    from bemlearn.apps.biped.sweep_stage import biped_run_stage

    return biped_run_stage()


def _run(config_path, out_dir=None, *, device=None, progress=True) -> Path:
    from bemlearn.apps.biped.pipeline import load_biped_config, run_biped_pipeline

    if device not in (None, "cpu"):
        raise ArgumentError(f"--device {device}: the biped pipeline trains on the CPU (set train.device in the config)")
    return run_biped_pipeline(load_biped_config(config_path), out_dir, progress=progress)


def _parse(config_path):
    from bemlearn.apps.biped.config import load_biped_config

    return load_biped_config(config_path)


APPLICATION = Application(
    name="biped",
    description="5-link planar biped, paper Section IV-B",
    robots={"biped": _pinned},
    add_cli=_cli,
    add_bench=_bench,
    run=_run,
    parse_config=_parse,
    sweep_stages={"biped-bem": _bem_stage, "run": _run_stage},
)
