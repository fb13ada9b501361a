"""Orchestration of the stages: configs, training runs, evaluation, closed-loop runs, reports."""

from bemlearn.pipeline.config import PipelineConfig, load_pipeline_config

__all__ = ["PipelineConfig", "load_pipeline_config"]
