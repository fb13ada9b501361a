"""Exported BEM predictors (TorchScript ``.pt``, torch.export ``.pt2``, AOTInductor package, C99 source) and checkpoints.

Everything here consumes a :class:`~bemlearn.models.predictor_state.PredictorState` plus
metadata, never a GPyTorch model.  The contract of the exported files is in
docs/predictor-contract.md.
"""

from bemlearn.export.aoti import AotiPredictor, load_aoti_predictor
from bemlearn.export.bem_predictor import EXPORTED_METHODS, BEMPredictor
from bemlearn.export.c_export import export_c
from bemlearn.export.c_source import c_sources
from bemlearn.export.checkpoint import (
    CHECKPOINT_FORMAT,
    CHECKPOINT_NAME,
    Checkpoint,
    load_checkpoint,
    load_learned_bem,
    write_checkpoint,
)
from bemlearn.export.export_run import ExportFormat, export_run
from bemlearn.export.folded_posterior import FoldedPosterior
from bemlearn.export.metadata import ARTIFACT_FORMAT, PredictorMetadata, artifact_metadata
from bemlearn.export.pt2 import Pt2Predictor, load_pt2_predictor, save_pt2
from bemlearn.export.staleness import check_predictor_matches, check_run_predictors, remove_stale_predictors
from bemlearn.export.torchscript import load_torchscript, save_torchscript, script_predictor
from bemlearn.export.variance_factor import VarianceFactor, variance_factor
from bemlearn.export.verify import reference_posterior, verify_predictor

__all__ = [
    "ARTIFACT_FORMAT",
    "AotiPredictor",
    "BEMPredictor",
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_NAME",
    "Checkpoint",
    "EXPORTED_METHODS",
    "ExportFormat",
    "FoldedPosterior",
    "PredictorMetadata",
    "Pt2Predictor",
    "VarianceFactor",
    "artifact_metadata",
    "c_sources",
    "export_c",
    "check_predictor_matches",
    "check_run_predictors",
    "export_run",
    "load_checkpoint",
    "load_aoti_predictor",
    "load_learned_bem",
    "load_pt2_predictor",
    "remove_stale_predictors",
    "load_torchscript",
    "reference_posterior",
    "save_pt2",
    "save_torchscript",
    "script_predictor",
    "variance_factor",
    "verify_predictor",
    "write_checkpoint",
]
