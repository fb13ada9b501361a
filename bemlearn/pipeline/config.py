"""The whole-pipeline configuration: one YAML file with a section per stage.

.. code-block:: yaml

    robot: furuta          # registry name or MJCF path (or leave it out and give data:)
    data: FILE             # train on this trajectory file instead of collecting (model-free without robot:)
    model: path/to/robot.xml  # model-free runs only: an MJCF to compare the learned BEM with
    collect: {...}         # bemlearn.data.collect.CollectConfig
    dataset: {...}         # bemlearn.data.dataset.DatasetConfig
    train: {...}           # bemlearn.fitting.GPConfig
    evaluate: {...}        # bemlearn.pipeline.evaluation.EvaluationConfig
    simulate: {...}        # bemlearn.sim.closed_loop.SimulateConfig

Every section is a strict dataclass defined next to its component; an unknown key
anywhere is an error naming the file and the key path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from bemlearn.data.collect import CollectConfig
from bemlearn.data.dataset import DatasetConfig
from bemlearn.fitting.gp_config import GPConfig
from bemlearn.pipeline.evaluation import EvaluationConfig
from bemlearn.sim.closed_loop import SimulateConfig

__all__ = ["PipelineConfig", "load_pipeline_config"]


@dataclass(frozen=True)
class PipelineConfig:
    """All stages' options: one YAML file with a section per stage.

    Attributes:
        robot: the robot: a registry name (``bemlearn robot list``) or the path of an MJCF file of this
            class (hinge/slide joints, exactly one no actuator drives). A path always means that file.
        data: a trajectory file to train on instead of collecting. Without ``robot`` the run is model-free.
        model: model-free runs only: a registry name or MJCF path whose model-based BEM the learned one
            is compared with (nothing is compared without it).
    """

    robot: str | None = None
    data: str | None = None
    model: str | None = None
    collect: CollectConfig = field(default_factory=CollectConfig)
    dataset: DatasetConfig = field(default_factory=DatasetConfig)
    train: GPConfig = field(default_factory=GPConfig)
    evaluate: EvaluationConfig = field(default_factory=EvaluationConfig)
    simulate: SimulateConfig = field(default_factory=SimulateConfig)

    def __post_init__(self) -> None:
        if self.robot is None and self.data is None:
            raise ValueError("the config names neither 'robot:' (a registry name or an MJCF path) nor 'data:' "
                             "(a trajectory file); a config needs at least one of them")
        if self.model is not None and self.robot is not None:
            raise ValueError("'model:' is for model-free runs (data: without robot:); with 'robot:' the robot's own "
                             "model is the ground truth")


def load_pipeline_config(path: str | Path) -> PipelineConfig:
    """Parse a pipeline YAML file strictly (unknown keys and bad types are errors naming the key) and
    fill in the values derived from the robot's model (:func:`~bemlearn.pipeline.resolve.resolve_pipeline_config`)."""
    from bemlearn.pipeline.resolve import resolve_pipeline_config

    return resolve_pipeline_config(path).config
