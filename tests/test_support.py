

def test_report_never_says_stayed_up_at_a_stable_equilibrium():
    from bemlearn.pipeline.report import _closed_loop_lines

    sim = {"predictor": {"fell": False, "diverged": False, "duration_s": 30.0, "tracking_rmse": 0.01, "qu_max": 0.02,
                         "u_max": 0.3, "real_time_factor": 50.0}}
    eq = {"joint": "hinge", "qu": 3.14159, "unit": "rad", "gravity_stiffness": -0.59, "stable_without_control": True}
    up = "\n".join(_closed_loop_lines(sim, {}, {"equilibrium": {**eq, "gravity_stiffness": 0.59, "stable_without_control": False}}, "rad"))
    down = "\n".join(_closed_loop_lines(sim, {}, {"equilibrium": eq}, "rad"))
    assert "| stayed up |" in up
    assert "stayed up" not in down and "stable without control (not balanced)" in down and "none of them balanced" in down
