"""Options of a walking simulation of the planar biped: the ``walk:`` section of ``configs/biped.yaml``.

:func:`~bemlearn.apps.biped.walker.simulate_walk` runs them; :class:`WalkConfig` and
:func:`load_walk_config` are re-exported by :mod:`bemlearn.apps.biped.walker`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bemlearn.apps.biped.controller import WalkExcitation, WalkingGains
from bemlearn.apps.biped.gait import GaitConfig
from bemlearn.config import ConfigError, config_folder, from_dict, load_yaml, rebase_paths
from bemlearn.data.sensors import SensorConfig

__all__ = ["WalkConfig", "load_walk_config", "PATH_KEYS"]


@dataclass(frozen=True)
class WalkConfig:
    """Walking simulation options (``walk:`` section of ``configs/biped.yaml``).

    Attributes:
        duration_s: simulated time limit, s.  rate_hz: control rate, Hz.
        max_steps: stop after this many steps (0: no limit).
        gait: which gait.  gains: controller gains.
        bem_source: ``"model"``, ``"zero"`` or ``"predictor"`` (torso BEM in the loop).
        predictor: exported predictor file for ``"predictor"``.
        sensor: encoder and velocity filter (set ``counts_per_rev: 0`` for exact angles).
        initial_phase: s at the start.  initial_phase_rate: ϑ̇ at the start, rad/s.
        initial_noise: std of a seeded perturbation of the initial actuated angles (at the same phase), rad.
        contact_height: foot-switch threshold above the foot sphere, m.
        min_step_phase: earliest phase at which a touchdown counts as a step.
        fall_hip_height: m.  fall_torso: rad.  max_step_time: s.
        seed: seeds the initial perturbation and the sensor noise.
        excitation: sum-of-sines excitation of the references (data collection; off by default).
    """

    duration_s: float = 10.0
    rate_hz: float = 115.0
    max_steps: int = 0
    gait: GaitConfig = field(default_factory=GaitConfig)
    gains: WalkingGains = field(default_factory=WalkingGains)
    bem_source: str = "model"
    predictor: str | None = None
    sensor: SensorConfig = field(default_factory=SensorConfig)
    initial_phase: float = 0.02
    initial_phase_rate: float = 1.0
    initial_noise: float = 0.0
    contact_height: float = 0.0005
    min_step_phase: float = 0.5
    fall_hip_height: float = 0.25
    fall_torso: float = 1.0
    max_step_time: float = 2.0
    seed: int = 0
    excitation: WalkExcitation = field(default_factory=WalkExcitation)

    def __post_init__(self) -> None:
        if self.duration_s <= 0 or self.rate_hz <= 0:
            raise ConfigError(f"walk: duration_s and rate_hz must be > 0, got {self.duration_s}, {self.rate_hz}")
        if self.max_steps < 0:
            raise ConfigError(f"walk.max_steps must be >= 0, got {self.max_steps}")


#: The keys of a biped config naming input files: in a file, relative to its folder (docs/config.md, "Paths").
PATH_KEYS: tuple[str, ...] = ("walk.predictor", "walk.gait.human.path", "gpdm.human.path")


def load_walk_config(path) -> WalkConfig:
    """The ``walk:`` section of a biped config file (e.g. ``configs/biped.yaml``), parsed strictly.

    Other top-level sections are left to their own parsers; ``robot``, when present, must be ``biped``.
    """
    data = rebase_paths(load_yaml(path), PATH_KEYS, config_folder(path))
    if data.get("application", "biped") != "biped":
        raise ConfigError(f"{path}: application: the walking simulation needs 'biped', got {data['application']!r}")
    if data.get("robot", "biped") != "biped":
        raise ConfigError(f"{path}: robot: the walking simulation needs 'biped', got {data['robot']!r}")
    return from_dict(WalkConfig, data.get("walk"), where=f"{path}:walk")
