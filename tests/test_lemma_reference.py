"""Lemma 1 along a reference its nodes resolve (bemlearn.pipeline.lemma.lemma1_reference), on the two-wheeler."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bemlearn.control.bem_sources import ModelBEM
from bemlearn.pipeline.lemma import learned_lemma1, lemma1_reference
from bemlearn.robots import MujocoRobot
from bemlearn.robots.reference import CompositeSinusoid

WHEELER = Path(__file__).parent / "robots" / "two_wheeler.xml"


def test_written_frequencies_that_repeat_after_1e4_s_are_taken_commensurate():
    """(0.1971, 0.3941) Hz — (0.2, 0.4)·λ/2π written to 4 digits — repeat after 1/gcd = 1e4 s: 256 nodes 39 s apart,
    each 7.7 cycles of 0.1971 Hz.  Taken as (f, 2f): (0.1971, 0.3942) Hz, period 1/0.1971 s; a resolved reference is
    kept as it is (the same object)."""
    ref = CompositeSinusoid.single((0.1268, 0.08456), (0.1971, 0.3941))
    assert ref.period == pytest.approx(1e4, rel=1e-12)
    out, how = lemma1_reference(ref)
    assert out.frequencies == ((0.1971, 2 * 0.1971),)
    assert out.amplitudes == ref.amplitudes and out.phases == ref.phases
    assert out.period == pytest.approx(1 / 0.1971, rel=1e-9)
    assert "commensurate" in how
    assert lemma1_reference(out) == (out, "")
    assert lemma1_reference(out)[0] is out
    # (1.0, 1.7) Hz: 10/17 — no ratio of denominator ≤ 12 within 1e-3; the period (10 s, 17 cycles) is resolved anyway
    kept = CompositeSinusoid.single((0.1, 0.1), (1.0, 1.7))
    assert lemma1_reference(kept)[0] is kept
    # (1.0, 1.2345) Hz: 1e4 s and no small ratio: kept, and the note says the check is aliased
    odd = CompositeSinusoid.single((0.1, 0.1), (1.0, 1.2345))
    out_odd, how_odd = lemma1_reference(odd)
    assert out_odd is odd and "aliased" in how_odd


def test_learned_lemma1_of_a_slightly_wrong_map_is_aliased_along_the_written_frequencies():
    """The model's own map with a spurious slope in q̇_u (f = f_model + c q̇_u, c = 0.005 s: a damping c Γ_q of
    c λ² = 0.15 per second per unit D_uu, the size the public balance_robot's learned map showed, 0.156) satisfies
    Lemma 1 up to that term: along (f, 2f) its ΔΓ correlates with the model's at r ≥ 0.99; along the written
    (0.1971, 0.3941) Hz, sampled at 256 nodes over 1e4 s, the spectral derivatives of the aliased sequence are
    ~1e4× too small, the spurious term dominates and r < 0.9."""
    robot = MujocoRobot.from_xml(WHEELER)
    model = ModelBEM(robot)

    def wrong_full(x: np.ndarray) -> np.ndarray:
        return model.full(x) + 0.005 * x[:, -1]

    written = CompositeSinusoid.single((0.1268, 0.08456), (0.1971, 0.3941))
    resolved, _ = lemma1_reference(written)
    r_written = learned_lemma1(model, wrong_full, robot, written).r
    r_resolved = learned_lemma1(model, wrong_full, robot, resolved).r
    assert r_resolved >= 0.99
    assert r_written < 0.9
    # the model's own map: r = 1 along the resolved reference
    assert learned_lemma1(model, model.full, robot, resolved).r == pytest.approx(1.0, abs=1e-6)


def test_delta_gamma_in_q_u_is_how_far_the_zero_dynamics_move_q_u():
    """``delta_gamma_qu`` = std(ΔΓ)/|Γ_q| against an independent computation with the model's own map: the q_u shift
    f(x^e) − f(x_0^e) that the BEM's own rates q̇_u^e, q̈_u^e make along the reference (eq. 14 vs eq. 11), whose std
    equals it to the linearization's order (ΔΓ ≈ Γ_q δ; 5e-7 relative here)."""
    from bemlearn.robots.zero_dynamics import spectral_derivative

    robot = MujocoRobot.from_xml(WHEELER)
    model = ModelBEM(robot)
    ref, _ = lemma1_reference(CompositeSinusoid.single((0.1268, 0.08456), (0.1971, 0.3941)))
    lem = learned_lemma1(model, model.full, robot, ref)
    qa, qad, qadd = ref.evaluate(lem.t)
    base = np.concatenate([qadd, qad, qa], axis=1)
    mu0 = np.asarray(model(np.ascontiguousarray(base)))
    x_e = np.concatenate([base, spectral_derivative(mu0, ref.period, 2)[:, None], spectral_derivative(mu0, ref.period, 1)[:, None]], 1)
    x_0 = np.concatenate([base, np.zeros((len(base), 2))], 1)
    shift = np.asarray(model.full(np.ascontiguousarray(x_e))) - np.asarray(model.full(np.ascontiguousarray(x_0)))
    assert lem.delta_gamma_qu > 0
    assert lem.delta_gamma_qu == pytest.approx(float(np.std(shift)), rel=1e-4)   # measured 5e-7
