"""The input checks of a loaded predictor whose compiled methods do not check shape and dtype themselves.

The TorchScript module checks its input inside (:class:`~bemlearn.export.bem_predictor.BEMPredictor`).
An exported program (``.pt2``) or an AOTInductor package checks only what its graph asserts:
B ≥ 1, and a finite mean (a non-finite input, or one too far from the data for float64, makes
the mean non-finite through the sentinel kernel column of
:mod:`bemlearn.export.folded_posterior`).  An AOTInductor method called with a float32 tensor,
the wrong width or a 1-D tensor *reads the memory as if it were right* and returns numbers.
:class:`CheckedPredictor` therefore checks rank, width, B, dtype and device before the call
(attribute reads only), and turns the graph's assertion into the TorchScript module's message,
naming the first non-finite entry (computed only when the assertion fired).  A contiguous CPU
float64 ``(B, n)`` tensor passes with four attribute reads (strides, width, dtype, device).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import torch

from bemlearn.errors import PredictorInputError

__all__ = ["CheckedPredictor", "nonfinite_message", "FULL_METHODS"]

#: Methods whose input is the full GP input (B, 3m + 2); the others take (B, 3m).
FULL_METHODS = ("predict_full", "full_mean", "predict_full_latent")


def nonfinite_message(x: torch.Tensor, method: str) -> str:
    """The TorchScript module's message for an input whose mean came out non-finite: the first
    NaN / ±inf entry, or (all entries finite) the range rule ‖u‖ > 10¹⁵⁰."""
    bad = torch.nonzero(~torch.isfinite(x))
    if bad.size(0) > 0:
        r, c = int(bad[0, 0]), int(bad[0, 1])
        return f"BEMPredictor.{method}: x[{r}, {c}] is {float(x[r, c])}; inputs must be finite ({bad.size(0)} non-finite entries)"
    return (f"BEMPredictor.{method}: x has finite entries too large to evaluate: the kernel cannot be evaluated in float64 "
            "(||(x - x_mean) / (x_std * lengthscale)|| above 1e150)")


class CheckedPredictor:
    """Methods with the BEMPredictor contract around compiled callables that do not check shape or dtype.

    Args:
        metadata_json: the predictor's metadata document (``inputs``, ``full_inputs``, ``units``).
        methods: contract method name → callable ``x -> result`` (a tuple (mean, std) or a mean).
            ``forward_latent`` / ``predict_full_latent`` may be missing (artifacts written before
            the calibrated band; ``forward`` / ``predict_full`` stand in), ``full_mean`` too
            (``predict_full``'s mean stands in).
    """

    def __init__(self, metadata_json: str, methods: dict[str, Callable[[torch.Tensor], Any]]) -> None:
        self.metadata_json = metadata_json
        doc = json.loads(metadata_json)
        units = doc.get("units", {})
        self._columns = {
            full: (len(doc[key]), ", ".join(f"{n} [{units.get(n, '?')}]" for n in doc[key]))
            for full, key in ((False, "inputs"), (True, "full_inputs"))
        }
        self._methods = dict(methods)
        # the strides of a contiguous (B, n) tensor: with the width, they check rank, width and layout
        self._strides = {m: (self._columns[m in FULL_METHODS][0], 1) for m in (*FULL_METHODS, "forward", "bem_mean",
                                                                             "forward_latent")}

    def _checked(self, x: Any, method: str) -> torch.Tensor:
        """``x`` as a contiguous tensor after the full check (the slow path of :meth:`_call`)."""
        n, columns = self._columns[method in FULL_METHODS]
        if (not isinstance(x, torch.Tensor) or x.dim() != 2 or x.size(1) != n or x.size(0) == 0
                or x.dtype != torch.float64 or x.device.type != "cpu"):
            shape = list(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
            dtype = x.dtype if isinstance(x, torch.Tensor) else "-"
            where = f" on {x.device}" if isinstance(x, torch.Tensor) and x.device.type != "cpu" else ""
            raise PredictorInputError(
                f"BEMPredictor.{method}: expected x of shape (B, {n}), B >= 1, and dtype torch.float64 with columns "
                f"[{columns}]; got shape {shape} and dtype {dtype}{where}"
            )
        return x.contiguous()

    def _call(self, fn: Callable[[torch.Tensor], Any], x: torch.Tensor, method: str) -> Any:
        """Check ``x`` as the TorchScript module does (same messages), then run ``fn`` on it.

        Fast path (four attribute reads): a contiguous CPU float64 ``(B, n)`` tensor; anything else
        takes the full check, which raises or makes the tensor contiguous.  B = 0 and non-finite
        entries are left to the compiled assertions.
        """
        try:
            stride = self._strides[method]   # (n, 1): with x.shape[1] == n, a contiguous (B, n) tensor
            fast = x.stride() == stride and x.shape[1] == stride[0] and x.dtype is torch.float64 and x.is_cpu
        except AttributeError:   # not a tensor
            fast = False
        if not fast:
            x = self._checked(x, method)
        try:
            return fn(x)
        except RuntimeError as exc:   # the graph's own assertions: B = 0, or a non-finite mean
            if "BEMPredictor." in str(exc):
                if x.size(0) == 0:
                    self._checked(x, method)   # raises the shape message
                raise PredictorInputError(nonfinite_message(x, method)) from None
            raise

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ(x_0^e), σ_band(x_0^e)) for ``x: (B, 3m)`` float64, each ``(B,)`` in q_u's unit (eq. 12, 14, B1).

        Raises:
            PredictorInputError: (a ValueError) wrong rank, width, dtype or device, B = 0, non-finite
                entries, or entries too large to evaluate (‖u‖ > 10¹⁵⁰).
        """
        return self._call(self._methods["forward"], x, "forward")

    def __call__(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward(x)

    def bem_mean(self, x: torch.Tensor) -> torch.Tensor:
        """μ(x_0^e) ``(B,)`` in q_u's unit for ``x: (B, 3m)`` float64 (eq. 14)."""
        return self._call(self._methods["bem_mean"], x, "bem_mean")

    def predict_full(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, σ_band) of f(x) (eq. 11, B1) for ``x: (B, 3m + 2)`` float64."""
        return self._call(self._methods["predict_full"], x, "predict_full")

    def full_mean(self, x: torch.Tensor) -> torch.Tensor:
        """Mean of the full learned map only (eq. 11), ``(B,)`` in q_u's unit."""
        if "full_mean" not in self._methods:
            return self._call(self._methods["predict_full"], x, "full_mean")[0]
        return self._call(self._methods["full_mean"], x, "full_mean")

    def forward_latent(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ(x_0^e), latent σ(x_0^e)) (eq. 12, 14); artifacts without the method return ``forward``
        (written before the calibrated band, when ``std`` was the latent std)."""
        return self._call(self._methods.get("forward_latent", self._methods["forward"]), x, "forward_latent")

    def predict_full_latent(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, latent σ) of f(x) (eq. 11, 12); see :meth:`forward_latent` for old artifacts."""
        fn = self._methods.get("predict_full_latent", self._methods["predict_full"])
        return self._call(fn, x, "predict_full_latent")

    def metadata(self) -> str:
        """The metadata JSON document."""
        return self.metadata_json
