"""Configuration of the biped pipeline: the sections of ``configs/biped.yaml`` and their loader.

:class:`BipedConfig` holds the walker (:class:`~bemlearn.apps.biped.walker.WalkConfig`) and one
strict dataclass per stage of :mod:`bemlearn.apps.biped.pipeline` (``collect``, ``dataset``,
``train``, ``evaluate``, ``gpdm``); :func:`load_biped_config` parses a file,
:func:`is_biped_config` tells a biped config from the other robots' pipeline configs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from bemlearn.apps.biped.controller import WalkExcitation
from bemlearn.apps.biped.human_gait import HumanGaitConfig
from bemlearn.apps.biped.walk_config import PATH_KEYS
from bemlearn.apps.biped.walker import WalkConfig
from bemlearn.config import config_folder, from_dict, load_yaml, rebase_paths
from bemlearn.errors import ConfigError
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.fitting.gpdm_fit import GPDMConfig

__all__ = ["WalkCollectConfig", "WalkDatasetConfig", "BipedEvaluateConfig", "BipedGPDMConfig", "BipedConfig",
           "load_biped_config", "is_biped_config"]


@dataclass(frozen=True)
class WalkCollectConfig:
    """Training walks (``collect:`` of a biped config); walk i uses seed ``seed + i``.

    Attributes:
        gaits: gait kinds walked (``default``, ``human``), ``walks_per_gait`` each.
        duration_s: simulated time per walk, s.
        step_length: (min, max) of the default gait's step length, drawn per walk, m.
        kp_u: (min, max) torso-loop stiffness drawn per walk, 1/s² (k_d,u = 2√k_p,u).
        initial_noise: std of the initial joint perturbation, rad.
        excitation: the reference excitation (its seed is replaced by the walk's seed).
        seed: first walk seed.
    """

    gaits: tuple[str, ...] = ("default", "human")
    walks_per_gait: int = 20
    duration_s: float = 4.0
    step_length: tuple[float, float] = (0.12, 0.16)
    kp_u: tuple[float, float] = (300.0, 600.0)
    initial_noise: float = 0.02
    excitation: WalkExcitation = field(default_factory=lambda: WalkExcitation(
        torso_amplitude=0.1, torso_frequency_hz=(0.2, 1.0), joint_amplitude=0.08, joint_frequency_hz=(0.1, 2.0)))
    seed: int = 0

    def __post_init__(self) -> None:
        if self.walks_per_gait < 1 or self.duration_s <= 0:
            raise ConfigError(f"collect: walks_per_gait >= 1 and duration_s > 0 expected, got "
                             f"{self.walks_per_gait}, {self.duration_s}")
        bad = [g for g in self.gaits if g not in ("default", "human")]
        if bad or not self.gaits:
            raise ConfigError(f"collect.gaits: expected a non-empty list of 'default' / 'human', got {list(self.gaits)}")


@dataclass(frozen=True)
class WalkDatasetConfig:
    """GP data from walks (``dataset:``), eq. (11).

    Attributes:
        derivatives: ``estimated`` (q̇, q̈ from the quantized angles: the sensor path) or
            ``truth`` (the simulator's q, q̇, q̈: a diagnostic upper bound).
        derivative, derivative_options: estimator (:mod:`bemlearn.data.derivatives`); Savitzky–Golay over 0.25 s
            with ``jump_factor`` 8, chosen by the learned-BEM error over 12 bench fits (docs/biped.md).
        skip_after_impact, skip_before_impact: samples dropped at the start / end of each step.
        jump_factor: the derivatives are estimated within segments: each step (the walker's foot
            strikes end it) is further cut at the velocity jumps found in the measured angles
            (a swing-foot scuff, a stall; :func:`~bemlearn.data.velocity_jumps.detect_velocity_jumps`,
            threshold ``jump_factor`` robust scales), so that no window spans one; ``null``: steps only.
        segment_edges: next to a jump, ``drop`` the samples whose window would be one-sided, or
            keep them (``one-sided``); :mod:`bemlearn.data.segmented_derivatives`.
        qu_window: keep |q1| ≤ this, rad.
        n_points: training points drawn at random.
        seed: seed of the draw.
    """

    derivatives: Literal["estimated", "truth"] = "estimated"
    derivative: str = "savgol"
    derivative_options: dict[str, Any] = field(default_factory=lambda: {"window_s": 0.25, "polyorder": 3})
    skip_after_impact: int = 16
    skip_before_impact: int = 12
    jump_factor: float | None = 8.0
    segment_edges: Literal["drop", "one-sided"] = "drop"
    qu_window: float = 0.5
    n_points: int = 1200
    seed: int = 0

    def __post_init__(self) -> None:
        from bemlearn.data import make_estimator

        make_estimator(self.derivative, self.derivative_options, where="dataset.derivative_options")
        if min(self.skip_after_impact, self.skip_before_impact) < 0 or self.n_points < 1 or not self.qu_window > 0:
            raise ConfigError(f"dataset: expected skips >= 0, n_points >= 1, qu_window > 0; got {self.skip_after_impact}, "
                             f"{self.skip_before_impact}, {self.n_points}, {self.qu_window}")
        if self.jump_factor is not None and not self.jump_factor > 0:
            raise ConfigError(f"dataset.jump_factor: expected a positive number or null, got {self.jump_factor!r}")
        if self.segment_edges not in ("drop", "one-sided"):
            raise ConfigError(f"dataset.segment_edges: expected 'drop' or 'one-sided', got {self.segment_edges!r}")


@dataclass(frozen=True)
class BipedEvaluateConfig:
    """Held-out walks and walks with the learned BEM (``evaluate:``).

    Attributes:
        gaits: gaits of the held-out walks and of the walks with the predictor.
        heldout_duration_s: held-out walk length, s (model BEM in the loop, no excitation).
        loop_duration_s: walks with the exported predictor in the loop, s.
        min_steps: consecutive steps required of a walk with the predictor.
        skip_after_impact: ticks after each touchdown left out of the single-support RMSE.
        oracle: also train on ground-truth derivatives and report its held-out RMSE.
        seed: first held-out seed (must not be a training seed).
    """

    gaits: tuple[str, ...] = ("default", "human")
    heldout_duration_s: float = 8.0
    loop_duration_s: float = 12.0
    min_steps: int = 20
    skip_after_impact: int = 16
    oracle: bool = True
    seed: int = 1000

    def __post_init__(self) -> None:
        if not self.gaits or any(g not in ("default", "human") for g in self.gaits):
            raise ConfigError(f"evaluate.gaits: expected a non-empty list of 'default' / 'human', got {list(self.gaits)}")
        if self.min_steps < 0 or self.skip_after_impact < 0:
            raise ConfigError(f"evaluate: min_steps and skip_after_impact must be >= 0, got {self.min_steps}, {self.skip_after_impact}")


@dataclass(frozen=True)
class BipedGPDMConfig:
    """GPDM of the robot's steps and of the human gait (``gpdm:``, eq. 16–17).

    Attributes:
        fit: :class:`~bemlearn.fitting.gpdm_fit.GPDMConfig`.
        first_step, steps: the robot steps fitted (after the start-up steps).
        human: the human data and its map into the robot's joint ranges.
        phase_bins: bins of the step phase for the human/robot comparison.
        threads: torch threads during GPDM fits (small matrices: 1 is fastest).
    """

    fit: GPDMConfig = field(default_factory=lambda: GPDMConfig(max_iter=200))
    first_step: int = 2
    steps: int = 6
    human: HumanGaitConfig = field(default_factory=HumanGaitConfig)
    phase_bins: int = 50
    threads: int = 1


@dataclass(frozen=True)
class BipedConfig:
    """A biped config file (``configs/biped.yaml``): the walker and the pipeline stages."""

    application: str = "biped"
    robot: str = "biped"
    walk: WalkConfig = field(default_factory=WalkConfig)
    collect: WalkCollectConfig = field(default_factory=WalkCollectConfig)
    dataset: WalkDatasetConfig = field(default_factory=WalkDatasetConfig)
    train: GPConfig = field(default_factory=GPConfig)
    evaluate: BipedEvaluateConfig = field(default_factory=BipedEvaluateConfig)
    gpdm: BipedGPDMConfig = field(default_factory=BipedGPDMConfig)

    def __post_init__(self) -> None:
        if self.application != "biped":
            raise ConfigError(f"application: a biped config needs 'biped', got {self.application!r}")
        if self.robot != "biped":
            raise ConfigError(f"robot: a biped config needs 'biped', got {self.robot!r}")
        n = len(self.collect.gaits) * self.collect.walks_per_gait
        if self.collect.seed <= self.evaluate.seed < self.collect.seed + n:
            raise ConfigError(f"evaluate.seed {self.evaluate.seed} is a training seed (collect.seed "
                             f"{self.collect.seed} … {self.collect.seed + n - 1}); held-out walks must differ")


def is_biped_config(path: str | Path) -> bool:
    """Whether the YAML file at ``path`` names ``application: biped``."""
    return load_yaml(path).get("application") == "biped"


def load_biped_config(path: str | Path) -> BipedConfig:
    """Parse a biped config strictly (unknown keys / bad types name the key path); its relative paths
    (:data:`~bemlearn.apps.biped.walk_config.PATH_KEYS`) are relative to the file's folder."""
    return from_dict(BipedConfig, rebase_paths(load_yaml(path), PATH_KEYS, config_folder(path)), where=str(path))
