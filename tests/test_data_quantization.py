"""Quantization detection on angles written as real loggers write them (issue 14)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bemlearn.data import counts_per_revolution, detect_quantization_step
from bemlearn.data.quantization import snap_to_grid

N = 2048
STEP = 2 * math.pi / N


def counts_walk(seed: int = 0, size: int = 20000, span: int = 150) -> np.ndarray:
    """Encoder counts of a slowly moving pendulum: a clipped random walk."""
    rng = np.random.default_rng(seed)
    return np.clip(np.cumsum(rng.integers(-2, 3, size=size)), -span, span)


def printed(x: np.ndarray, fmt: str) -> np.ndarray:
    return np.array([float(fmt % v) for v in x])


@pytest.mark.parametrize(
    "name",
    ["float64", "float32", "deg %.6f", "deg %.4f", "deg %.2f", "counts*360/N %.5f + offset", "float32 deg", "near-duplicates"],
)
def test_logger_written_grid_is_found(name):
    k = counts_walk()
    q = k * STEP
    deg = k * (360.0 / N)
    values = {
        "float64": q,
        "float32": q.astype(np.float32).astype(np.float64),
        "deg %.6f": np.radians(printed(np.degrees(q), "%.6f")),
        "deg %.4f": np.radians(printed(deg, "%.4f")),
        "deg %.2f": np.radians(printed(deg, "%.2f")),  # round-off up to 2.8 % of the step
        "counts*360/N %.5f + offset": np.radians(printed(deg + 17.3, "%.5f")),
        "float32 deg": np.radians((deg.astype(np.float32)).astype(np.float64)),
        "near-duplicates": np.where(np.arange(len(q)) % 3 == 0, q.astype(np.float32).astype(np.float64), q),
    }[name]
    step = detect_quantization_step(values)
    assert step is not None
    # the printed decimals bound the step's error: ≤ half a last digit over the level span
    assert step == pytest.approx(STEP, rel=1e-5)
    assert counts_per_revolution(step) == N


def test_noise_and_continuous_values_are_not_quantized():
    rng = np.random.default_rng(1)
    q = counts_walk() * STEP
    assert detect_quantization_step(q + rng.normal(scale=0.02 * STEP, size=q.shape)) is None
    assert detect_quantization_step(np.sin(np.linspace(0, 10, 5000))) is None
    assert detect_quantization_step(rng.normal(size=500)) is None
    assert detect_quantization_step(np.full(50, 0.3)) is None


def test_sparse_levels_and_coarser_grid():
    rng = np.random.default_rng(2)
    q = 0.37 + STEP * rng.integers(-3000, 3000, size=2000)
    assert detect_quantization_step(q) == pytest.approx(STEP, rel=1e-10)
    even = 2 * STEP * rng.integers(-500, 500, size=2000)  # every other count never used: the grid is 2δ
    assert detect_quantization_step(even) == pytest.approx(2 * STEP, rel=1e-10)


def test_snap_to_grid_uses_the_reference_offset():
    ref = 0.01 + STEP * np.arange(-20, 20)
    mid = np.array([0.01 + 3.4 * STEP, 0.01 - 7.6 * STEP])
    np.testing.assert_allclose(snap_to_grid(mid, STEP, ref), [0.01 + 3 * STEP, 0.01 - 8 * STEP], rtol=0, atol=1e-15)
