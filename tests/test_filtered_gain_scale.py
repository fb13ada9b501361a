"""The excitation's sampled loop with the collection's velocity filter (derive.filtered_feedback_radius) against
the recursion itself, and the gain-scale rule that uses it."""

from __future__ import annotations

import numpy as np
import pytest

from bemlearn.pipeline.derive import _robust_gain_scale, filtered_feedback_radius

DT = 0.005


def _double_integrator(w: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zero-order-hold tick map of q̈ = u (Δt = 5 ms) and critically damped PD gains u = −ω² q − 2ω q̇."""
    A = np.array([[1.0, DT], [0.0, 1.0]])
    B = np.array([[DT * DT / 2], [DT]])
    return A, B, np.array([[-w * w, -2 * w]])


def test_radius_is_that_of_the_filtered_recursion():
    """ρ against the eigenvalues of the map z_k → z_{k+1}, z = [x, v_{k−1}, y_{k−1}], built column by column by one
    step of the recursion as collect runs it: y = q, v ← a v + b (y − y_prev), u = K_q y + K_v v, x ← A x + B u
    (1e-12), for a filter slower and faster than the loop."""
    A, B, K = _double_integrator(48.0)
    for wc in (30.0, 300.0):
        a, b = (2 - wc * DT) / (2 + wc * DT), 2 * wc / (2 + wc * DT)
        cols = []
        for e in np.eye(4):
            x, v, y_prev = e[:2], e[2:3], e[3:]
            y = x[:1]
            v = a * v + b * (y - y_prev)
            u = K[:, :1] @ y + K[:, 1:] @ v
            cols.append(np.concatenate([A @ x + B @ u, v, y]))
        rho = float(np.max(np.abs(np.linalg.eigvals(np.array(cols).T))))
        assert filtered_feedback_radius(A, B, K, n=1, rate_hz=1 / DT, velocity_cutoff=wc) == pytest.approx(rho, abs=1e-12)


def test_gain_scale_narrows_where_the_filter_destabilises_the_scalings():
    """ω = 48 rad/s PD on a double integrator: with exact rates all ±40 % scalings are stable; with a 30 rad/s
    filter (ρ = 0.992 unscaled) 75 % of them are, and the range narrows to ±20 % with a note; a 300 rad/s filter
    changes nothing (the result and note of the exact-rate rule)."""
    A, B, K = _double_integrator(48.0)
    assert _robust_gain_scale(A, B, K, rate_hz=1 / DT, velocity_cutoff=300.0) == ((0.6, 1.4), 1.0, "")
    scale, frac, note = _robust_gain_scale(A, B, K, rate_hz=1 / DT, velocity_cutoff=30.0)
    assert scale == (0.8, 1.2) and frac == 1.0
    assert "±40 % keeps only 75 %" in note
