"""Orchestration of the stages: configs (resolved from the model), training runs, evaluation, closed-loop runs, reports."""

from typing import TYPE_CHECKING

from bemlearn._lazy import lazy_namespace

if TYPE_CHECKING:  # imported on first use: bemlearn._lazy
    from bemlearn.pipeline.config import PipelineConfig
    from bemlearn.pipeline.data_evaluation import SliceSpec, bem_slice_figure, bem_slices, heldout_prediction
    from bemlearn.pipeline.evaluation import BEMEvaluation, EvaluationConfig, evaluate_bem, held_out_references, run_truth_robot
    from bemlearn.pipeline.gp_stage import CheckpointProvenance, GPStageResult, fit_bem_gp
    from bemlearn.pipeline.lemma import LearnedLemma1, learned_lemma1
    from bemlearn.pipeline.reliability import reliability_figure, reliability_table
    from bemlearn.pipeline.resolve import ResolvedConfig, complete_section, load_pipeline_config, resolve_pipeline_config
    from bemlearn.pipeline.results import CollectResult, DataSummary, LoopResult, RunResult, SimulateResult, TrainResult
    from bemlearn.pipeline.run import run_pipeline
    from bemlearn.pipeline.train import train_run
    from bemlearn.pipeline.workers import default_jobs, worker_pool

__all__ = [
    "reliability_table",
    "reliability_figure",
    "BEMEvaluation",
    "CollectResult",
    "DataSummary",
    "LoopResult",
    "RunResult",
    "SimulateResult",
    "TrainResult",
    "CheckpointProvenance",
    "EvaluationConfig",
    "GPStageResult",
    "LearnedLemma1",
    "PipelineConfig",
    "ResolvedConfig",
    "SliceSpec",
    "bem_slice_figure",
    "bem_slices",
    "complete_section",
    "evaluate_bem",
    "fit_bem_gp",
    "held_out_references",
    "heldout_prediction",
    "learned_lemma1",
    "load_pipeline_config",
    "resolve_pipeline_config",
    "run_pipeline",
    "run_truth_robot",
    "train_run",
    "default_jobs",
    "worker_pool",
]

__getattr__, __dir__ = lazy_namespace(__name__, __file__)
