"""The walking controller: EIC internal loop (eq. 8), null-space tracking, BEM query, leg mirroring."""

from __future__ import annotations

import numpy as np
import pytest

from bemlearn.apps.biped.controller import WalkingController, WalkingGains
from bemlearn.apps.biped.gait import GaitConfig, build_gait, stance_frame
from bemlearn.control.bem_sources import ModelBEM, ZeroBEM
from bemlearn.robots import load


@pytest.fixture(scope="module")
def biped():
    return load("biped")


@pytest.fixture(scope="module")
def gait():
    return build_gait(GaitConfig())


def _state(gait, s=0.4, seed=0):
    rng = np.random.default_rng(seed)
    q = gait.posture(s) + rng.normal(0, 0.03, 5)
    qd = np.r_[0.2, gait.evaluate(s)[1] * 2.0] + rng.normal(0, 0.1, 5)
    return q, qd


def test_internal_loop_sets_torso_acceleration_and_null_space_follows_external(biped, gait):
    """With the exact model the closed loop gives q̈1 = v_u and q̈_a = v_ext off the D_ua direction."""
    gains = WalkingGains()
    ctrl = WalkingController(biped, ModelBEM(biped), gait, gains=gains)
    q, qd = _state(gait)
    u, info = ctrl(q, qd, 1)
    tau = info["tau"]
    assert np.all(np.abs(tau) < gains.torque_limit)  # not saturated: the identities hold exactly
    D, h = biped.terms(q, qd)
    qdd = np.linalg.solve(D, np.r_[0.0, tau] - h)
    assert qdd[0] == pytest.approx(info["v_u"], abs=1e-9)
    # the external law of the module docstring, evaluated independently
    s, sd = gait.phase(q, qd)
    qa_d, qad_d, qadd_d = gait.reference(s, sd)
    S = np.array([1.0, 0, 1.0, 0])
    v_ext = (qadd_d - gains.kd * (qd[1:] + S * qd[0] - qad_d)
             - gains.kp * (q[1:] + S * (q[0] - gait.torso) - qa_d) - S * info["v_u"])
    d = D[0, 1:] / np.linalg.norm(D[0, 1:])
    P = np.eye(4) - np.outer(d, d)
    np.testing.assert_allclose(P @ qdd[1:], P @ v_ext, atol=1e-9)
    np.testing.assert_array_equal(u, tau)  # leg 1 in stance: actuator order is the stance order


def test_bem_is_queried_on_the_desired_gait(biped, gait):
    ctrl = WalkingController(biped, ModelBEM(biped), gait)
    q, qd = _state(gait, s=0.6)
    _, info = ctrl(q, qd, 1)
    s, sd = gait.phase(q, qd)
    h, h1, h2 = gait.evaluate(s)
    np.testing.assert_allclose(info["bem_x"], np.r_[h2 * sd**2, h1 * sd, h], atol=1e-14)
    # q1^e is the root of Γ_0 of the pinned model at that query (eq. 9)
    qa, qad, qadd = h, h1 * sd, h2 * sd**2
    assert abs(biped.gamma0_scalar(info["qu_e"], qa, qad, qadd)) < 1e-9


def test_leg_two_in_stance_is_the_mirror_image(biped, gait):
    ctrl = WalkingController(biped, ZeroBEM(), gait)
    q, qd = _state(gait, seed=4)
    u1, _ = ctrl(q, qd, 1)
    u2, _ = ctrl(stance_frame(q, 2), stance_frame(qd, 2), 2)
    np.testing.assert_allclose(u2, u1[[2, 3, 0, 1]], atol=1e-12)


def test_invalid_bem_value_is_held_and_counted(biped, gait):
    ctrl = WalkingController(biped, lambda x: np.full(x.shape[0], np.nan), gait)
    q, qd = _state(gait)
    _, info = ctrl(q, qd, 1)
    assert ctrl.bem_invalid == 1 and info["qu_e"] == gait.torso


def test_rejects_other_robots_and_bad_gains(gait):
    with pytest.raises(ValueError, match="5-link biped"):
        WalkingController(load("furuta"), ZeroBEM(), gait)
    with pytest.raises(ValueError, match="gains.kp_u must be >= 0"):
        WalkingGains(kp_u=-1.0)
