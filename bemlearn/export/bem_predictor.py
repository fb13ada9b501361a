"""The exported BEM predictor: μ(x_0^e) and its std (eq. 12, 14) behind a checked interface.

``BEMPredictor`` is an ``nn.Module`` that ``torch.jit.script`` compiles and ``torch.export``
traces.  Its methods (the contract of docs/predictor-contract.md):

    forward(x)       x: (B, 3m) float64 [q̈_a, q̇_a, q_a] (rad/s², rad/s, rad)
                     → (mean (B,), std (B,)) rad: μ(x_0^e), σ_band(x_0^e), x_0^e = [x, 0, 0]  (eq. 14)
    bem_mean(x)      same input → mean (B,) rad only (the control-loop path)
    predict_full(x)  x: (B, 3m + 2) [q̈_a, q̇_a, q_a, q̈_u, q̇_u] → (mean, std) of f(x)  (eq. 11)
    forward_latent(x), predict_full_latent(x)
                     the same means with the latent posterior std of f (eq. 12), the ``std``
                     of artifacts written before the calibrated band
    metadata()       JSON string (robot, columns, units, model, provenance)

``std`` is the calibrated band σ_band² = c² σ² + max(Σ_i (s_i ∂μ/∂x_i)², σ_est²) over the method's
input columns, σ_est the mean's spread over the neighbouring derivative estimators
(:mod:`bemlearn.models.band`, docs/uncertainty.md); c, s and the estimators are in the metadata.

Inputs of the wrong rank, width or dtype, an empty batch, and non-finite inputs raise
ValueError from inside the TorchScript module (``torch.jit.Error`` in Python, message
``...ValueError: BEMPredictor.<method>: ...``).
"""

import json
import math

import torch
from torch import nn

from bemlearn.errors import PredictorInputError
from bemlearn.export.folded_posterior import FoldedPosterior
from bemlearn.export.metadata import PredictorMetadata, artifact_metadata
from bemlearn.export.variance_factor import variance_factor
from bemlearn.models.predictor_state import PredictorState

__all__ = ["BEMPredictor", "EXPORTED_METHODS", "LATENT_METHODS"]

#: Methods besides ``forward`` that the TorchScript artifact exports.
EXPORTED_METHODS = ("bem_mean", "predict_full", "full_mean", "forward_latent", "predict_full_latent", "metadata")
#: Exported methods that artifacts written before the calibrated band lack (their ``std`` is latent).
LATENT_METHODS = ("forward_latent", "predict_full_latent")


def _dtype_name(x: torch.Tensor) -> str:
    if x.dtype == torch.float32:
        return "torch.float32"
    if x.dtype == torch.float16:
        return "torch.float16"
    if x.dtype == torch.bfloat16:
        return "torch.bfloat16"
    if x.dtype == torch.int64:
        return "torch.int64"
    if x.dtype == torch.int32:
        return "torch.int32"
    if x.dtype == torch.bool:
        return "torch.bool"
    if x.dtype == torch.float64:
        return "torch.float64"
    return "a non-float64 dtype"


class BEMPredictor(nn.Module):
    """Learned BEM μ(x_0^e) (eq. 14) and the full GP map f(x) (eq. 11) in physical units.

    Args:
        state: the frozen float64 posterior (any kind: exact, sgpr, svgp).
        metadata: the validated metadata; ``m`` fixes the input widths 3m and 3m + 2.
        exact_rtol: see :func:`~bemlearn.export.variance_factor.variance_factor`.
    """

    n_bem: int
    n_full: int
    bem_columns: str
    full_columns: str
    metadata_json: str

    def __init__(self, state: PredictorState, metadata: PredictorMetadata, *, exact_rtol: float = 1e-6) -> None:
        super().__init__()
        doc = artifact_metadata(metadata, state)
        factor = variance_factor(state, exact_rtol=exact_rtol)
        self.n_bem = 3 * metadata.m
        self.n_full = state.dim
        self.full = FoldedPosterior(state, factor, n_inputs=self.n_full)
        self.bem = FoldedPosterior(state, factor, n_inputs=self.n_bem, share=self.full)
        units = doc["units"]
        self.bem_columns = ", ".join(f"{n} [{units[n]}]" for n in doc["inputs"])
        self.full_columns = ", ".join(f"{n} [{units[n]}]" for n in doc["full_inputs"])
        self.metadata_json = json.dumps(doc, allow_nan=False)

    # ---- checks (cheap on success; the message is built only on failure) ----------------
    def _check_input(self, x: torch.Tensor, n: int, method: str, columns: str) -> None:
        if x.dim() != 2 or x.size(1) != n or x.size(0) == 0 or x.dtype != torch.float64:
            if torch.jit.is_scripting():
                raise ValueError(
                    f"BEMPredictor.{method}: expected x of shape (B, {n}), B >= 1, and dtype torch.float64 with columns "
                    f"[{columns}]; got shape {x.shape} and dtype {_dtype_name(x)}"
                )
            else:
                raise PredictorInputError(
                    f"BEMPredictor.{method}: expected x of shape (B, {n}), B >= 1, and dtype torch.float64 with columns "
                    f"[{columns}]; got shape {list(x.shape)} and dtype {x.dtype}"
                )

    def _nonfinite_message(self, x: torch.Tensor, method: str) -> str:
        bad = torch.nonzero(~torch.isfinite(x))
        if bad.size(0) > 0:
            r, c = int(bad[0, 0]), int(bad[0, 1])
            return f"BEMPredictor.{method}: x[{r}, {c}] is {float(x[r, c])}; inputs must be finite ({bad.size(0)} non-finite entries)"
        return (f"BEMPredictor.{method}: x has finite entries too large to evaluate: the kernel cannot be evaluated in float64 "
                "(||(x - x_mean) / (x_std * lengthscale)|| above 1e150)")

    def _check_finite(self, mean: torch.Tensor, x: torch.Tensor, method: str) -> None:
        # A non-finite x, or one too far from the data for float64 (||u|| > 1e150), always makes the mean
        # non-finite (sentinel column, see FoldedPosterior),
        # so one reduction of the (B,) mean replaces a pass over x.
        if torch.jit.is_scripting():
            total = float(mean) if mean.size(0) == 1 else float(mean.sum())
            if not abs(total) < math.inf:
                raise ValueError(self._nonfinite_message(x, method))
        elif torch.compiler.is_exporting():
            torch._assert_async(
                torch.isfinite(mean).all(),
                f"BEMPredictor.{method}: x has non-finite entries (NaN or inf) or entries too large to evaluate",
            )
        elif not bool(torch.isfinite(mean).all()):
            raise PredictorInputError(self._nonfinite_message(x, method))

    # ---- the contract --------------------------------------------------------------------
    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """BEM mean and calibrated std: ``x: (B, 3m)`` float64 [q̈_a (rad/s²), q̇_a (rad/s), q_a (rad)];
        returns (μ(x_0^e), σ_band(x_0^e)), each ``(B,)`` rad (eq. 14, B1)."""
        self._check_input(x, self.n_bem, "forward", self.bem_columns)
        mean, std = self.bem.mean_band(x)
        self._check_finite(mean, x, "forward")
        return mean, std

    @torch.jit.export
    def forward_latent(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """As :meth:`forward` with the latent posterior std of f (eq. 12) instead of the band."""
        self._check_input(x, self.n_bem, "forward_latent", self.bem_columns)
        mean, std = self.bem.mean_std(x)
        self._check_finite(mean, x, "forward_latent")
        return mean, std

    @torch.jit.export
    def bem_mean(self, x: torch.Tensor) -> torch.Tensor:
        """BEM mean only: ``x: (B, 3m)`` as in :meth:`forward`; returns μ(x_0^e) ``(B,)`` rad."""
        self._check_input(x, self.n_bem, "bem_mean", self.bem_columns)
        mean = self.bem.mean(x)
        self._check_finite(mean, x, "bem_mean")
        return mean

    @torch.jit.export
    def predict_full(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Full learned map f (eq. 11): ``x: (B, 3m + 2)`` float64 [q̈_a, q̇_a, q_a, q̈_u, q̇_u];
        returns (mean, σ_band), each ``(B,)`` rad (eq. B1 over all 3m + 2 columns)."""
        self._check_input(x, self.n_full, "predict_full", self.full_columns)
        mean, std = self.full.mean_band(x)
        self._check_finite(mean, x, "predict_full")
        return mean, std

    @torch.jit.export
    def predict_full_latent(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """As :meth:`predict_full` with the latent posterior std of f (eq. 12)."""
        self._check_input(x, self.n_full, "predict_full_latent", self.full_columns)
        mean, std = self.full.mean_std(x)
        self._check_finite(mean, x, "predict_full_latent")
        return mean, std

    @torch.jit.export
    def full_mean(self, x: torch.Tensor) -> torch.Tensor:
        """Mean of the full learned map f (eq. 11) only: ``x: (B, 3m + 2)`` as in
        :meth:`predict_full`; returns ``(B,)`` rad (the control-loop path for momentum-corrected EIC)."""
        self._check_input(x, self.n_full, "full_mean", self.full_columns)
        mean = self.full.mean(x)
        self._check_finite(mean, x, "full_mean")
        return mean

    @torch.jit.export
    def metadata(self) -> str:
        """The metadata JSON document (see :func:`~bemlearn.export.metadata.artifact_metadata`)."""
        return self.metadata_json
