"""Reliability of a Gaussian band: observed coverage against nominal level (eq. 13).

For a nominal level η the band is μ ± κ_η σ with κ_η = Φ⁻¹((1 + η)/2) (1.96 for 95 %);
its observed coverage is the fraction of errors e = μ − q_u^e with |e| ≤ κ_η σ.  A
calibrated band has coverage ≈ η at every level; coverage below η means violations of
the bound of eq. (13)/(15) more often than stated.  :func:`reliability_figure` draws the
diagram for the report and TensorBoard (``writer.add_figure``).
"""

from __future__ import annotations

import numpy as np

from bemlearn.errors import ArgumentError
from bemlearn.fitting.calibration import gaussian_quantile

__all__ = ["NOMINAL_LEVELS", "reliability_figure", "reliability_table"]

#: Nominal levels of the reliability diagram (50–99 %).
NOMINAL_LEVELS = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99)


def reliability_table(errors: np.ndarray, std: np.ndarray, levels=NOMINAL_LEVELS) -> list[dict]:
    """Coverage of ``errors (P,)`` by ``±κ_η std (P,)`` (same unit) at each nominal level.

    Returns:
        one dict per level: ``level``, ``kappa`` and observed ``coverage`` (fractions).
    """
    e = np.abs(np.asarray(errors, dtype=np.float64))
    s = np.asarray(std, dtype=np.float64)
    if e.shape != s.shape or e.ndim != 1 or e.size == 0:
        raise ArgumentError(f"reliability_table: errors and std must be equal-length non-empty 1-D arrays, got {e.shape} and {s.shape}")
    rows = []
    for level in levels:
        kappa = gaussian_quantile(level)
        rows.append({"level": float(level), "kappa": kappa, "coverage": float(np.mean(e <= kappa * s))})
    return rows


def reliability_figure(tables: dict[str, list[dict]], *, title: str = "reliability of the BEM band"):
    """Coverage vs nominal level, one line per band (``{label: reliability_table(...)}``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.5, 4.2))
    ax.plot([0.45, 1.0], [0.45, 1.0], "k:", lw=1, label="calibrated")
    for i, (label, rows) in enumerate(tables.items()):
        ax.plot([r["level"] for r in rows], [r["coverage"] for r in rows], "o-", color=f"C{i}", ms=4, label=label)
    ax.set_xlabel("nominal level η")
    ax.set_ylabel("observed coverage")
    ax.set_xlim(0.45, 1.0)
    ax.set_ylim(0.0, 1.02)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return fig
