"""Joint support of the BEM queries ((S1), (S2) of bemlearn.pipeline.data_evaluation) and the verdict's
support and equilibrium checks, on synthetic lockstep vs spread data with a known BEM."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from bemlearn.pipeline.support import EXTRAPOLATION_T, extrapolation_leverage, support_of_queries
from bemlearn.pipeline.verdict import judge_run

NAMES = ("qdd_a", "qd_a", "q_a", "qdd_u", "qd_u")
S_A, S_P, LAM2 = 0.04, -1.0, 67.0          # a pendubot-like BEM q_u^e = s_p q_a + s_a q̈_a, λ² = Γ_q / D_uu (1/s²)


def synthetic(lockstep: bool, n: int = 500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Samples of the linearised unactuated row D_uu q̈_u = Γ_q (q_u − q_u^e) + d, i.e.
    q_u = q_u^e + (q̈_u − d / D_uu) / λ².

    lockstep: a balancing controller ties q̈_u = b q̈_a and only the disturbance d moves q̈_u off that
    line (q̈_u = b q̈_a + d / D_uu), so q_u carries no trace of q̈_u apart from q̈_a.
    spread: the ratio q̈_u / q̈_a varies with the reference's frequency (b ∈ [−3, −1]) and d = 0.
    """
    rng = np.random.default_rng(seed)
    qdd_a, q_a, qd_a = rng.normal(0, 5, n), rng.normal(0, 0.05, n), rng.normal(0, 0.3, n)
    if lockstep:
        d_over_duu = rng.normal(0, 1.0, n)
        qdd_u = -2.8 * qdd_a + d_over_duu
    else:
        d_over_duu = np.zeros(n)
        qdd_u = rng.uniform(-3.0, -1.0, n) * qdd_a + rng.normal(0, 0.3, n)
    qd_u = -0.9 * qd_a + rng.normal(0, 0.05, n)
    y = S_P * q_a + S_A * qdd_a + (qdd_u - d_over_duu) / LAM2 + rng.normal(0, 3e-4, n)
    return np.c_[qdd_a, qd_a, q_a, qdd_u, qd_u], y


def test_support_ratio_is_the_mahalanobis_nearest_neighbour_distance():
    x, _ = synthetic(False, n=300)
    q = x[:50].copy()
    q[:, 3:] = 0.0
    got = support_of_queries(x, q)
    vi = np.linalg.inv(np.cov(x, rowvar=False))
    dtt = cdist(x, x, "mahalanobis", VI=vi)
    np.fill_diagonal(dtt, np.inf)
    spacing = np.median(dtt.min(1))
    np.testing.assert_allclose(got["spacing"], spacing, rtol=1e-9)
    np.testing.assert_allclose(got["ratio"], cdist(q, x, "mahalanobis", VI=vi).min(1) / spacing, rtol=1e-8)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lockstep_data_do_not_resolve_the_extrapolation_spread_data_do(seed):
    xl, yl = synthetic(True, seed=seed)
    xs, ys = synthetic(False, seed=seed)
    lock, spread = extrapolation_leverage(xl, yl, NAMES), extrapolation_leverage(xs, ys, NAMES)
    assert abs(lock["t"]) < 2.0 < EXTRAPOLATION_T                   # the slope in q̈_u is not there
    assert spread["t"] > 4 * EXTRAPOLATION_T
    assert spread["lambda2"] == pytest.approx(LAM2, rel=0.05)        # the data's 1/slope is λ²
    # the geometry is alike: q̈_u = 0 at large |q̈_a| lies beyond both data sets (|corr| > 0.9)
    for x in (xl, xs):
        assert abs(np.corrcoef(x[:, 0], x[:, 3])[0, 1]) > 0.9
        q = x.copy()
        q[:, 3:] = 0.0
        assert support_of_queries(x, q)["share"] < 0.9


def _support_metrics(x: np.ndarray, y: np.ndarray) -> dict:
    from bemlearn.pipeline.support import _lockstep_pairs

    q = x.copy()
    q[:, 3:] = 0.0
    s = support_of_queries(x, q)
    sup = s["supported"]
    inputs = [{"input": n, "unit": "rad/s^2", "data": list(np.quantile(x[:, i], [0.025, 0.975])),
               "supported": list(np.quantile(q[sup, i], [0.025, 0.975])), "reach": float(np.abs(q[sup, i]).max())}
              for i, n in enumerate(NAMES[:3])]
    return {"support": {"share": s["share"], "pairs": _lockstep_pairs(x, NAMES, 3), "inputs": inputs,
                        **extrapolation_leverage(x, y, NAMES)}}


def test_verdict_flips_on_lockstep_data_and_names_the_inputs():
    lock = judge_run(_support_metrics(*synthetic(True)))
    assert lock.status == "unusable" and lock.findings[0].check == "support"
    reason = lock.reasons[0]
    assert "qdd_u ≈ -2.8" in reason and "·qdd_a (corr -0.99" in reason, reason
    assert "no training sample near qdd_u = 0 beyond |qdd_a|" in reason and "bemlearn excite CONFIG" in reason
    assert judge_run(_support_metrics(*synthetic(False))).status == "ok"


def test_resolution_advice_drops_amplitude_when_inputs_move_in_lockstep():
    m = _support_metrics(*synthetic(True))
    m["resolution"] = {"ratio": 3.0, "spread": 0.002, "band_std": 0.0007,
                       "inputs": [{"input": "qdd_a", "share": 0.0008, "amplitude": 5.0, "unit": "rad/s^2"}]}
    text = next(f.reason for f in judge_run(m).findings if f.check == "resolution")
    assert "that amplitude" not in text and "cannot help" in text


def test_data_from_a_stable_equilibrium_are_never_a_balanced_upright():
    x, y = synthetic(False)
    rng = np.random.default_rng(3)
    y_hanging = y - 2 * x[:, 3] / LAM2 + rng.normal(0, 1e-5, len(y))      # q_u − q_u^e = −q̈_u / |λ²|: stable
    v = judge_run(_support_metrics(x, y_hanging))
    assert v.status == "unusable" and "stable without control" in v.reasons[0]


def test_equilibrium_check_refuses_a_hanging_branch():
    from bemlearn.pipeline.feasibility import equilibrium_stiffness
    from bemlearn.robots import MujocoRobot

    src = (Path(__file__).parent / "robots" / "cartpole.xml").read_text()
    upright = MujocoRobot.from_xml_string(src)
    hanging = MujocoRobot.from_xml_string(src.replace("<worldbody>", '<custom><numeric name="bemlearn_qu_nominal" '
                                                      'data="3.141592653589793"/></custom><worldbody>', 1))
    up, down = equilibrium_stiffness(upright), equilibrium_stiffness(hanging)
    assert up["gravity_stiffness"] > 0 and not up["stable_without_control"]
    # Γ_q at the hanging branch is the upright's with the sign flipped (m g l cos q_u)
    assert down["gravity_stiffness"] == pytest.approx(-up["gravity_stiffness"], rel=1e-4) and down["stable_without_control"]
    assert judge_run({"equilibrium": up}).status == "ok"
    v = judge_run({"equilibrium": down})
    assert v.status == "unusable" and v.findings[0].check == "equilibrium" and "not the upright" in v.reasons[0]


def test_report_never_says_stayed_up_at_a_stable_equilibrium():
    from bemlearn.pipeline.report import _closed_loop_lines
    from bemlearn.pipeline.run_metrics import DataInfo, LoopMetrics, RunMetrics

    sim = {"predictor": LoopMetrics.from_dict({"fell": False, "diverged": False, "duration_s": 30.0, "tracking_rmse": 0.01,
                                               "qu_max": 0.02, "u_max": 0.3, "real_time_factor": 50.0})}
    eq = {"joint": "hinge", "qu": 3.14159, "unit": "rad", "gravity_stiffness": -0.59, "stable_without_control": True}
    held = {"equilibrium": {**eq, "gravity_stiffness": 0.59, "stable_without_control": False}}
    up = "\n".join(_closed_loop_lines(sim, DataInfo(), RunMetrics.from_dict(held), "rad"))
    down = "\n".join(_closed_loop_lines(sim, DataInfo(), RunMetrics.from_dict({"equilibrium": eq}), "rad"))
    assert "| stayed up |" in up
    assert "stayed up" not in down and "stable without control (not balanced)" in down and "none of them balanced" in down
