"""Bézier virtual constraints, phase variable, leg swap and leg kinematics of the biped gaits."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bemlearn.apps.biped.gait import (
    LEG_SWAP,
    BezierGait,
    GaitConfig,
    GaitDesign,
    build_gait,
    design_gait,
    leg_fk,
    leg_ik,
    stance_frame,
)
from bemlearn.apps.biped.model import BipedParameters
from bemlearn.robots import load

P = BipedParameters()
KW = dict(L_t=P.L_t, L_s=P.L_s)
C = (1.0, 1.0, 0.5, 0.0, 0.0)


def _poly_samples(n=41):
    """Stance-relative samples whose actuated joints are cubic polynomials in the phase."""
    s = np.linspace(0, 1, n)
    qa = np.stack([-0.4 + 0.6 * s, 0.3 + 0.2 * s - 0.1 * s**3, 0.3 - 0.7 * s**2, 0.2 + s - s**2], 1)
    # q1 chosen so that θ = cᵀq = −0.2 + 0.5 s exactly (linear in s)
    q1 = -0.2 + 0.5 * s - qa @ np.array(C[1:])
    return s, np.c_[q1, qa]


def test_fit_reproduces_polynomials_and_phase_is_linear():
    s, q = _poly_samples()
    gait = BezierGait.fit(q, degree=5, phase_weights=C)
    assert gait.theta_start == pytest.approx(-0.2, abs=1e-14) and gait.theta_end == pytest.approx(0.3, abs=1e-14)
    for sk, qk in zip(s[::5], q[::5]):
        np.testing.assert_allclose(gait.evaluate(sk)[0], qk[1:], atol=1e-12)
        ph, _ = gait.phase(qk, np.zeros(5))
        assert ph == pytest.approx(sk, abs=1e-12)
        np.testing.assert_allclose(gait.posture(sk), qk, atol=1e-12)


def test_derivatives_match_finite_differences():
    gait = design_gait()
    eps = 1e-5
    for s in (0.1, 0.37, 0.8):
        h, h1, h2 = gait.evaluate(s)
        hp, hm = gait.evaluate(s + eps)[0], gait.evaluate(s - eps)[0]
        np.testing.assert_allclose(h1, (hp - hm) / (2 * eps), rtol=0, atol=1e-7)
        np.testing.assert_allclose(h2, (hp - 2 * h + hm) / eps**2, rtol=0, atol=2e-4)
    _qa, qad, qadd = gait.reference(0.4, 2.0, 3.0)
    h, h1, h2 = gait.evaluate(0.4)
    np.testing.assert_allclose(qad, 2.0 * h1, atol=1e-14)
    np.testing.assert_allclose(qadd, 4.0 * h2 + 3.0 * h1, atol=1e-13)


def test_endpoints_are_pinned_and_evaluation_is_clamped():
    _s, q = _poly_samples()
    gait = BezierGait.fit(q, degree=4, phase_weights=C)
    a = np.asarray(gait.coefficients)
    np.testing.assert_allclose(a[:, 0], q[0, 1:], atol=1e-15)
    np.testing.assert_allclose(a[:, -1], q[-1, 1:], atol=1e-15)
    np.testing.assert_allclose(gait.evaluate(1.3)[0], a[:, -1], atol=1e-15)
    np.testing.assert_allclose(gait.evaluate(-0.2)[0], a[:, 0], atol=1e-15)


def test_fit_rejects_a_non_monotone_phase_and_bad_shapes():
    _, q = _poly_samples()
    q = q.copy()
    q[10, 0] = q[9, 0] - 0.5  # θ drops between samples 9 and 10
    with pytest.raises(ValueError, match="between samples 9 and 10"):
        BezierGait.fit(q, degree=5, phase_weights=C)
    with pytest.raises(ValueError, match=r"shape \(n, 5\)"):
        BezierGait.fit(q[:, :4], degree=5, phase_weights=C)
    with pytest.raises(ValueError, match="theta_end"):
        BezierGait(((0.0,) * 3,) * 4, C, 0.3, 0.1)


def test_stance_frame_swaps_legs_and_is_an_involution():
    q = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    np.testing.assert_array_equal(stance_frame(q, 1), q)
    np.testing.assert_array_equal(stance_frame(q, 2), [0.1, 0.4, 0.5, 0.2, 0.3])
    np.testing.assert_array_equal(stance_frame(stance_frame(q, 2), 2), q)
    batch = np.arange(15.0).reshape(3, 5)
    np.testing.assert_array_equal(stance_frame(batch, 2), batch[:, list(LEG_SWAP)])
    with pytest.raises(ValueError, match="stance_leg must be 1 or 2"):
        stance_frame(q, 0)


def test_leg_kinematics_match_mujoco_and_invert():
    """leg_fk against the pinned model's swing foot (a downward leg) in MuJoCo."""
    biped = load("biped")
    g = torch.Generator().manual_seed(3)
    q = (torch.rand(12, 5, generator=g, dtype=torch.float64) - 0.5) * 1.2
    fk = biped.forward_kinematics(q, ["hip", "foot2"])
    rel = (fk["foot2"] - fk["hip"]).numpy()
    qn = q.numpy()
    mine = leg_fk(qn[:, 0] + qn[:, 3], qn[:, 4], **KW)
    np.testing.assert_allclose(mine, rel[:, [0, 2]], atol=1e-12)
    thigh, knee = leg_ik(mine[:, 0], mine[:, 1], **KW)
    np.testing.assert_allclose(leg_fk(thigh, knee, **KW), mine, atol=1e-12)
    with pytest.raises(ValueError, match="out of the leg's reach"):
        leg_ik(np.array([0.0]), np.array([-0.5]), **KW)


def test_default_design_geometry():
    d = GaitDesign()
    gait = design_gait(d)
    q0, q1 = gait.posture(0.0), gait.posture(1.0)
    # start: stance foot L/2 ahead of the hip at hip height; swing foot L behind the stance foot
    st0 = leg_fk(q0[0] + q0[1], q0[2], **KW)
    sw0 = leg_fk(q0[0] + q0[3], q0[4], **KW)
    np.testing.assert_allclose(st0, [d.step_length / 2, -d.hip_height], atol=1e-12)
    np.testing.assert_allclose(sw0 - st0, [-d.step_length, 0.0], atol=1e-12)
    # end: swing foot L ahead, touchdown_depth below the ground
    st1 = leg_fk(q1[0] + q1[1], q1[2], **KW)
    sw1 = leg_fk(q1[0] + q1[3], q1[4], **KW)
    np.testing.assert_allclose(sw1 - st1, [d.step_length, -d.touchdown_depth], atol=1e-12)


def test_human_gait_feet_level_at_impact_and_clear_in_swing():
    cfg = GaitConfig(kind="human")
    gait = build_gait(cfg)
    for s in (0.0, 1.0):
        q = gait.posture(s)
        st = leg_fk(q[0] + q[1], q[2], **KW)
        sw = leg_fk(q[0] + q[3], q[4], **KW)
        assert abs(sw[1] - st[1]) < 1e-12
    s = np.linspace(0.15, 0.85, 15)
    heights = []
    for sk in s:
        q = gait.posture(sk)
        heights.append(leg_fk(q[0] + q[3], q[4], **KW)[1] - leg_fk(q[0] + q[1], q[2], **KW)[1])
    heights = np.asarray(heights)
    # the arc is imposed on the human time phase, the gait runs on θ: compare its peak and
    # require the foot well above the ground through mid-swing
    assert heights.max() == pytest.approx(cfg.human_clearance, abs=0.003)
    assert heights.min() > 0.015


def test_build_gait_rejects_unknown_kind():
    with pytest.raises(ValueError, match="gait.kind"):
        build_gait(GaitConfig(kind="robot"))  # type: ignore[arg-type]

