"""Orchestration of the stages: configs, training runs, evaluation, closed-loop runs, reports."""

from bemlearn.pipeline.config import PipelineConfig, load_pipeline_config
from bemlearn.pipeline.evaluation import EvaluationConfig, evaluate_bem, held_out_references
from bemlearn.pipeline.lemma import learned_lemma1
from bemlearn.pipeline.reliability import reliability_figure, reliability_table
from bemlearn.pipeline.run import run_pipeline
from bemlearn.pipeline.train import train_run

__all__ = [
    "reliability_table",
    "reliability_figure",
    "EvaluationConfig",
    "PipelineConfig",
    "evaluate_bem",
    "held_out_references",
    "learned_lemma1",
    "load_pipeline_config",
    "run_pipeline",
    "train_run",
]
