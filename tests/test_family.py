"""The robot family of issue 28 (bemlearn/bench/family): generator determinism, every file compiles, and the
oracle checked against closed forms and independent computations."""

import math

import mujoco
import numpy as np
import pytest

from bemlearn.bench.family.generator import TOPOLOGIES, generate_robot
from bemlearn.bench.family.oracle import Oracle, wrap_angle


def test_same_seed_same_bytes():
    for i in (0, 5, 10):
        a = generate_robot(3, i, hold_check=False)
        b = generate_robot(3, i, hold_check=False)
        assert a[0] == b[0] and a[1] == b[1]
    assert generate_robot(3, 0, hold_check=False)[0] != generate_robot(4, 0, hold_check=False)[0]


@pytest.mark.parametrize("index", range(12))
def test_every_file_compiles_and_its_upright_is_an_unstable_equilibrium(index):
    xml, truth = generate_robot(0, index, hold_check=False)
    m = mujoco.MjModel.from_xml_string(xml)
    assert m.nu == truth["m"] and m.nv == truth["m"] + 1
    assert truth["topology"] == TOPOLOGIES[index % len(TOPOLOGIES)]
    up = truth["upright_check"]
    assert up["ok"] and up["unstable"] and up["energy_max"] and abs(up["residual"]) < 1e-9
    # the upright by construction is the potential energy's maximum found without being told
    assert abs(float(wrap_angle(Oracle(xml).qu_star - truth["qu_upright"]))) < 1e-9
    # the pole's centre of mass is straight above its hinge there
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    d.qpos[Oracle(xml).u] = truth["qu_upright"]
    mujoco.mj_kinematics(m, d)
    pole = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "pole")
    jnt = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "pole")
    r = d.xipos[pole] - d.xanchor[jnt]
    assert r[2] > 0 and math.hypot(r[0], r[1]) < 1e-9 * max(1.0, r[2]) + 1e-12


# ---- the oracle's BEM against closed forms --------------------------------------------------------------------------

G = 9.81


def _indices(topology, n=3, seed=0):
    out = [i for i in range(60) if TOPOLOGIES[i % len(TOPOLOGIES)] == topology]
    return out[:n]


def _queries(oracle, n=40, seed=0):
    rng = np.random.default_rng(seed)
    sc = oracle.scales()
    qa = oracle.qa0 + 0.5 * rng.uniform(-1, 1, (n, oracle.m)) * np.array([hi - lo for lo, hi in sc["pos"]])
    qd = rng.uniform(-1, 1, (n, oracle.m)) * np.array(sc["vel"])
    qdd = rng.uniform(-1, 1, (n, oracle.m)) * np.array(sc["acc"])
    return qa, qd, qdd


@pytest.mark.parametrize("index", _indices("cartpole"))
def test_cartpole_bem_is_atan_of_the_cart_acceleration(index):
    """Pole on a cart (hinge about y): q_u^e − q_u* = atan(ẍ/g) whatever x, ẋ, the pole's inertia or the cart's damping."""
    xml, truth = generate_robot(0, index, hold_check=False)
    o = Oracle(xml, truth["qu_upright"])
    qa, qd, qdd = _queries(o)
    got = o.bem(qa, qd, qdd)
    want = truth["qu_upright"] + np.arctan(qdd[:, 0] / G)
    np.testing.assert_allclose(got, want, atol=1e-9)


@pytest.mark.parametrize("index", [i for i in _indices("xy_cart", 6)][:4])
def test_xy_cart_bem_is_atan_of_the_acceleration_in_the_swing_plane(index):
    """x-y cart (optionally on a turntable ψ, at ψ̇ = ψ̈ = 0): q_u^e − q_u* = atan((ẍ cos ψ + ÿ sin ψ)/g)."""
    xml, truth = generate_robot(0, index, hold_check=False)
    o = Oracle(xml, truth["qu_upright"])
    qa, qd, qdd = _queries(o)
    if o.m == 3:
        qd[:, 2] = 0.0
        qdd[:, 2] = 0.0
    psi = qa[:, 2] if o.m == 3 else np.zeros(len(qa))
    want = truth["qu_upright"] + np.arctan((qdd[:, 0] * np.cos(psi) + qdd[:, 1] * np.sin(psi)) / G)
    np.testing.assert_allclose(o.bem(qa, qd, qdd), want, atol=1e-9)


@pytest.mark.parametrize("index", _indices("reaction_wheel"))
def test_reaction_wheel_bem_balances_the_wheel_reaction_against_gravity(index):
    """sin(q_u^e − q_u*) = I_w φ̈ / (g Σ m_i l_i): the wheel's axial inertia (from the body inertia, rotated to the
    world) against the pendulum's gravity moment (from body masses and centre heights at the upright); φ, φ̇ drop out."""
    xml, truth = generate_robot(0, index, hold_check=False)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    o = Oracle(xml, truth["qu_upright"])
    d.qpos[:] = o.qa0_full()
    mujoco.mj_kinematics(m, d)
    jp = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "pole")
    ml = sum(m.body_mass[b] * (d.xipos[b][2] - d.xanchor[jp][2])
             for b in (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("pole", "wheel")))
    w = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "wheel")
    R = d.ximat[w].reshape(3, 3)
    axis = d.xaxis[jp]
    iw = float(axis @ (R @ np.diag(m.body_inertia[w]) @ R.T) @ axis)
    qa, qd, qdd = _queries(o)
    want = truth["qu_upright"] + np.arcsin(iw * qdd[:, 0] / (G * ml))
    np.testing.assert_allclose(o.bem(qa, qd, qdd), want, atol=1e-9)


@pytest.mark.parametrize("topology", ["pendubot", "arm2_pole"])
def test_serial_arm_static_bem_keeps_the_pole_vertical(topology):
    """At rest the pole on a serial arm of hinges about y is upright in the world: q_u^e = q_u* − Σ (q_a − q_a0)."""
    for index in _indices(topology, 2):
        xml, truth = generate_robot(0, index, hold_check=False)
        o = Oracle(xml, truth["qu_upright"])
        qa, _, _ = _queries(o)
        z = np.zeros_like(qa)
        want = truth["qu_upright"] - (qa - o.qa0).sum(axis=1)
        np.testing.assert_allclose(o.bem(qa, z, z), want, atol=1e-9)


def test_bem_is_a_root_of_the_unactuated_inverse_dynamics_row_on_every_topology():
    for index in range(6):
        xml, truth = generate_robot(0, index, hold_check=False)
        o = Oracle(xml, truth["qu_upright"])
        q = o.design_queries(30, seed=2)
        assert q["qa"].shape[0] == 30 and np.all(np.abs(q["bem"] - truth["qu_upright"]) <= 0.2)
        for k in range(30):
            tau = o.inverse(q["qa"][k], q["bem"][k], q["qda"][k], q["qdda"][k])
            assert abs(tau[o.u]) < 1e-9


# ---- conventions: the same robot written differently is the same physics -----------------------------------------

def _trajectory(xml, qu_star, qu_offset, steps=300):
    m = mujoco.MjModel.from_xml_string(xml)
    o = Oracle(xml, qu_star)
    d = mujoco.MjData(m)
    d.qpos[:] = o.qa0_full()
    d.qpos[o.u] += qu_offset
    d.ctrl[:] = o.rest_control()
    out = []
    for _ in range(steps):
        mujoco.mj_step(m, d)
        out.append(np.concatenate([d.qpos - o.qa0_full(), d.qvel]))
    return np.array(out), o


@pytest.mark.parametrize("index", [1, 4, 8])
def test_degrees_radians_ref_and_geometry_give_the_same_physics(index):
    base = {"degrees": False, "tilt": 0.0, "ref": 0.0, "hanging_by_fromto": False}
    variants = [dict(base), dict(base, degrees=True), dict(base, tilt=math.pi), dict(base, ref=math.pi),
                dict(base, tilt=math.pi, hanging_by_fromto=True, degrees=True), dict(base, ref=-1.1, degrees=True),
                dict(base, tilt=0.7)]
    ref_traj = None
    for v in variants:
        xml, truth = generate_robot(0, index, hold_check=False, conventions=v)
        assert abs(float(wrap_angle(truth["qu_upright"] - wrap_angle(v["ref"] - v["tilt"])))) < 1e-12
        traj, o = _trajectory(xml, truth["qu_upright"], 0.05)
        assert abs(float(wrap_angle(Oracle(xml).qu_star - truth["qu_upright"]))) < 1e-9  # the energy maximum finds it
        if ref_traj is None:  # compared until the falling pole nears a joint range (limits: a constraint solve)
            n = int(np.argmax(np.abs(traj[:, o.u]) > 0.4)) or len(traj)
            ref_traj = traj[:n]
        traj = traj[: len(ref_traj)]
        # actuator sizes are written with 6 digits and sized on each variant: agree to that precision
        np.testing.assert_allclose(traj, ref_traj, rtol=0, atol=1e-4 * max(1.0, np.abs(ref_traj).max()))
    assert np.abs(ref_traj[-1, :]).max() > 1e-3  # the pole moved: the comparison has content


# ---- holdability ---------------------------------------------------------------------------------------------------

def test_a_robot_sized_below_its_demand_cannot_hold_and_says_which_actuator():
    _, truth = generate_robot(0, 6)  # drawn infeasible by its force limit
    assert truth["designed_holdable"] is False and truth["holdable"] is False
    assert "cannot hold the design region" in truth["hold"]["reason"] and "cart_act" in truth["hold"]["reason"]
    assert truth["hold"]["static_ratio"] > 1.0


def test_a_robot_sized_above_its_demand_is_balanced_by_the_oracle_lqr_with_friction_on():
    index = next(i for i in range(64) if generate_robot(0, i, hold_check=False)[1]["features"]["friction"]
                 and generate_robot(0, i, hold_check=False)[1]["designed_holdable"])
    xml, truth = generate_robot(0, index)
    assert truth["holdable"] is True and truth["hold"]["static_ratio"] <= 1.0 and truth["hold"]["lqr_ok"]
    assert mujoco.MjModel.from_xml_string(xml).dof_frictionloss.max() > 0


# ---- the bench's scoring, fast: a predictor built on the oracle's own BEM, saved and loaded like a run's ---------

def _predictor_file(tmp_path, xml, truth, *, scale=1.0, offset=0.0, n=300):
    """An exact-GP posterior (fixed hyperparameters) on oracle BEM samples, q_u = q* + scale (q_u^e − q*) + offset,
    saved with bemlearn's TorchScript writer."""
    import dataclasses

    import torch

    from bemlearn.export import BEMPredictor, save_torchscript
    from bemlearn.export.metadata import PredictorMetadata
    from bemlearn.models.predictor_state import PredictorState

    o = Oracle(xml, truth["qu_upright"])
    q = o.design_queries(n, seed=11, bound=0.25)
    m = o.m
    X = np.concatenate([q["qdda"], q["qda"], q["qa"], np.zeros((len(q["bem"]), 2))], axis=1)
    y = truth["qu_upright"] + scale * (q["bem"] - truth["qu_upright"]) + offset
    X, y = torch.from_numpy(X), torch.from_numpy(y)
    xm, xs = X.mean(0), X.std(0).clamp_min(1e-3)
    xs[3 * m:] = 1.0
    names = tuple([f"qdd_{j}" for j in truth["actuated_joints"]] + [f"qd_{j}" for j in truth["actuated_joints"]]
                  + [f"q_{j}" for j in truth["actuated_joints"]] + ["qdd_pole", "qd_pole"])
    f64 = dict(dtype=torch.float64)
    ls = torch.tensor([1.0] * m + [30.0] * (2 * m) + [10.0, 10.0], **f64)
    state = PredictorState(kind="exact", Z=(X - xm) / xs, alpha=torch.zeros(len(y), **f64), S=torch.zeros(len(y), len(y), **f64),
                           lengthscale=ls, outputscale=torch.tensor(1.0, **f64), noise=torch.tensor(1e-6, **f64), x_mean=xm,
                           x_std=xs, y_mean=y.mean(), y_std=y.std(), input_names=names, n_train=len(y))
    L = torch.linalg.cholesky(state.gram())
    alpha = torch.cholesky_solve(((y - y.mean()) / y.std())[:, None], L)[:, 0]
    state = dataclasses.replace(state, alpha=alpha, S=torch.cholesky_inverse(L))
    units = {nm: "m/s^2" for nm in names}
    meta = PredictorMetadata(robot=truth["name"], joint_names=(*truth["actuated_joints"], "pole"),
                             actuated_names=tuple(truth["actuated_joints"]), unactuated_name="pole", m=m, input_names=names,
                             units=units, n_train=len(y), n_inducing=None, hyperparameters={}, bemlearn_version="test",
                             data_sha256="0" * 64)
    return save_torchscript(BEMPredictor(state, meta), tmp_path / "bem_predictor.pt")


def test_compare_predictor_scores_a_right_and_two_wrong_learned_bems(tmp_path):
    from bemlearn.bench.family.score import N_QUERIES, compare_predictor

    xml, truth = generate_robot(0, 6, hold_check=False)  # a cart-pole whose upright is not at 0 (geometry)
    assert truth["features"]["upright_at"] == "other"
    right = compare_predictor(_predictor_file(tmp_path, xml, truth), xml, truth)
    assert right["rmse"] < 2e-3 and abs(right["gain"] - 1) < 0.02 and right["n_queries"] == N_QUERIES
    assert math.isnan(right["probe_error"])
    assert 0.0 <= right["band_coverage"] <= 1.0
    flat = compare_predictor(_predictor_file(tmp_path, xml, truth, scale=0.5), xml, truth)
    assert abs(flat["gain"] - 0.5) < 0.02 and flat["rmse"] > 0.02
    # the same BEM one turn of the hinge away is the same angle: not an error
    turned = compare_predictor(_predictor_file(tmp_path, xml, truth, offset=2 * math.pi), xml, truth)
    assert turned["rmse"] < 2e-3
    hanging = compare_predictor(_predictor_file(tmp_path, xml, truth, offset=math.pi), xml, truth)
    assert hanging["rmse"] > 3.0


def test_a_predictor_the_bench_cannot_read_is_named_under_the_table_not_only_counted(tmp_path):
    """An ok run whose predictor file this tree refuses (another tree's exporter, or damage) counts as a false ok, and
    the table says which run and why, with the way to score it."""
    import json

    from bemlearn.bench.family.score import score_run, unscored_note

    xml, truth = generate_robot(0, 6, hold_check=False)
    truth = {**truth, "holdable": True, "hold": {"reason": "not checked here"}}
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.json").write_text(json.dumps({"verdict": {"status": "ok", "findings": []}}))
    (run / "bem_predictor.pt").write_bytes(b"PK\x03\x04 not a predictor")
    row = score_run(run, xml, truth, {"exit_code": 0})
    assert row["verdict"] == "ok" and row["false_ok"] is True and row["rmse"] is None
    note = unscored_note([row])
    assert note.startswith("\nNot scored (1)") and f"- {truth['name']} (verdict ok): " in note and "--checkout TREE" in note
    assert unscored_note([{**row, "compare_error": None}]) == ""


def test_the_runs_worst_point_is_one_more_query_moved_into_the_oracles_box(tmp_path):
    """The run's own worst design-region point (here 10× the box's velocity, a slide rate a cart-pole's BEM does not
    depend on, and 10× its position span) is clipped into the
    oracle's box and scored there: its error is |learned − oracle| at the clipped motion, computed independently."""
    import torch

    from bemlearn.bench.family.score import N_QUERIES, compare_predictor
    from bemlearn.export.torchscript import load_torchscript

    xml, truth = generate_robot(0, 6, hold_check=False)
    pred = _predictor_file(tmp_path, xml, truth, scale=0.5)
    o = Oracle(xml, truth["qu_upright"])
    sc = o.scales()
    joint = truth["actuated_joints"][0]
    x0e = [0.7 * sc["acc"][0], -10 * sc["vel"][0], 10 * sc["pos"][0][1]]
    got = compare_predictor(pred, xml, truth, n_queries=64, probe={"names": [joint], "x0e": x0e})
    assert got["n_queries"] == 65
    qa, qd, qdd = o.clip_to_box(np.array([x0e[2]]), np.array([x0e[1]]), np.array([x0e[0]]))
    assert qdd[0] == x0e[0] and qd[0] == pytest.approx(-sc["vel"][0], rel=1e-12) and qa[0] == pytest.approx(sc["pos"][0][1], rel=1e-12)
    want = o.bem(qa[None], qd[None], qdd[None])[0]
    with torch.no_grad():
        learned = float(load_torchscript(pred).bem_mean(torch.tensor([[qdd[0], qd[0], qa[0]]], dtype=torch.float64))[0])
    assert got["probe_error"] == pytest.approx(abs(learned - want), abs=1e-12)
    assert got["probe_error"] > 0.05          # the half-gain BEM where the acceleration tilts the pole by ~0.14 rad
    # a probe naming other joints is not scored
    other = compare_predictor(pred, xml, truth, n_queries=64, probe={"names": ["elsewhere"], "x0e": x0e})
    assert other["n_queries"] == 64 and math.isnan(other["probe_error"])
    assert N_QUERIES == 4096


def test_balance_and_reason_judgements_and_the_table():
    from bemlearn.bench.family.score import balanced_at_upright, feature_table, judge_reason

    up = {"closed_loop": {"predictor": {"fell": False, "diverged": False, "qu_max": 3.2}}}
    assert balanced_at_upright(up, math.pi)[0] is True
    assert balanced_at_upright(up, 0.0)[0] is False  # a loop that stayed near ±π did not balance an upright at 0
    hanging = {"closed_loop": {"predictor": {"fell": False, "diverged": False, "qu_max": 0.07}}}
    assert balanced_at_upright(hanging, math.pi)[0] is False and balanced_at_upright(hanging, 0.0)[0] is True
    assert balanced_at_upright({"closed_loop": {"predictor": {"fell": True}}}, 0.0)[0] is False
    # stayed up near the upright while the arm left its reference: balanced there (the note says the arm drifted)
    drifted = balanced_at_upright({"closed_loop": {"predictor": {"fell": False, "diverged": True, "qu_max": 0.48}}}, 0.385)
    assert drifted[0] is True and "left the reference" in drifted[1]
    assert balanced_at_upright({"closed_loop": {"predictor": {"fell": False, "diverged": True, "qu_max": 0.9}}}, 0.385)[0] is False
    assert balanced_at_upright({}, 0.0)[0] is None
    assert judge_reason("the model says it cannot be balanced over the design region", holdable=True, bem_right=None)[0] is False
    assert judge_reason("the model says it cannot be balanced over the design region", holdable=False, bem_right=None)[0] is True
    assert judge_reason("all 24 excitation trials fell", holdable=True, bem_right=None)[0] is False
    assert judge_reason("held-out RMSE 0.05 rad", holdable=True, bem_right=False)[0] is True
    assert judge_reason("x", holdable=True, bem_right=None, check="model:hold")[0] is False
    assert judge_reason("x", holdable=True, bem_right=True, check="closed_loop")[0] is False
    assert judge_reason("x", holdable=True, bem_right=False, check="closed_loop")[0] is True
    assert judge_reason("x", holdable=True, bem_right=True, check="resolution")[0] is False
    # a band reason is judged by the band's coverage of the oracle BEM, which can be too narrow around a right mean
    band = "the exported ±2σ band holds only 56 % of the model BEM over the design region"
    assert judge_reason(band, holdable=True, bem_right=True, check="band", band_coverage=0.6)[0] is True
    assert judge_reason(band, holdable=True, bem_right=True, check="band", band_coverage=0.95)[0] is False
    assert judge_reason(band, holdable=True, bem_right=True, check="band")[0] is False   # no coverage: by the mean
    # a BEM on the hanging branch: "max 0.044 rad" names the wrong cause, "the hanging equilibrium" the right one
    assert judge_reason("max 0.044 rad", holdable=True, bem_right=False, check="design_region", off_branch=True)[0] is False
    assert judge_reason("the learned BEM is the hanging branch", holdable=True, bem_right=False, check="design_region",
                        off_branch=True)[0] is True
    rows = [dict(name=f"r{i}", actuator_kind=k, friction=False, m=1, upright_at="0", zero_by="plain", angle="radian",
                 holdable=h, verdict=v, right=r, false_ok=f, rmse=e, gain=g, reason_true=t)
            for i, (k, h, v, r, f, e, g, t) in enumerate([("motor", True, "ok", True, False, 1e-3, 1.0, None),
                                                           ("motor", True, "ok", False, True, 0.1, 0.5, None),
                                                           ("position", False, "unusable", False, False, None, None, True)])]
    table = {(t["feature"], t["value"]): t for t in feature_table(rows)}
    assert table[("all", "")]["count"] == 3 and table[("all", "")]["holdable"] == 2 and table[("all", "")]["false_ok"] == 1
    assert table[("actuator_kind", "motor")]["ok_rate"] == 0.5 and table[("actuator_kind", "position")]["reason_true"] == 1
    assert table[("actuator_kind", "motor")]["median_gain"] == 0.75


# ---- the whole chain on a small fixed sample (slow: three zero-config `bemlearn run`s) -------------------------------

@pytest.mark.slow
def test_three_family_robots_zero_config_through_the_pipeline_and_scored(tmp_path):
    """fam0_000 (a plain cart-pole, velocity servo), fam0_002 (reaction wheel, zero by ref and geometry, degrees) and
    fam0_003 (pendubot, upright at π by geometry), each `bemlearn run` on `robot: FILE`, scored against the oracle."""
    from bemlearn.bench.family.family_bench import run_family

    res = run_family(0, 6, tmp_path, only=[0, 2, 3])
    rows = {r["name"]: r for r in res["rows"]}
    assert set(rows) == {"fam0_000", "fam0_002", "fam0_003"}
    for r in rows.values():
        assert r["verdict"] in ("ok", "degraded", "unusable", "error", "crash", "none")
        assert r["false_ok"] == (r["verdict"] == "ok" and not (r["bem_right"] and r["balanced_at_upright"]))
    cart = rows["fam0_000"]  # the class's easiest member: right, on today's pipeline already
    assert cart["holdable"] and cart["verdict"] == "ok" and cart["right"], cart
    assert cart["rmse"] <= 0.01 and 0.95 <= cart["gain"] <= 1.05
    for f in ("results.csv", "results.json", "table.md"):
        assert (tmp_path / f).is_file()
    assert "| all |  | 3 |" in (tmp_path / "table.md").read_text()


def test_a_loaded_or_in_memory_predictor_scores_as_its_file(tmp_path):
    """compare_module takes what compare_predictor loads: the same dict for the same predictor, and an object that is
    not a file (here the loaded module behind a plain wrapper) names itself in the error when its joints are others."""
    from bemlearn.bench.family.score import compare_module, compare_predictor
    from bemlearn.errors import CheckpointError
    from bemlearn.export.torchscript import load_torchscript

    xml, truth = generate_robot(0, 6, hold_check=False)
    pred = _predictor_file(tmp_path, xml, truth, scale=0.5)
    from_file = compare_predictor(pred, xml, truth, n_queries=64)
    loaded = load_torchscript(pred)

    class Wrapped:
        def __call__(self, x):
            return loaded(x)

        def bem_mean(self, x):
            return loaded.bem_mean(x)

        def metadata(self):
            return loaded.metadata()

    assert compare_module(Wrapped(), xml, truth, n_queries=64) == pytest.approx(from_file, nan_ok=True)
    other = dict(truth, actuated_joints=["elsewhere"])
    with pytest.raises(CheckpointError, match="^the fit in memory: actuated inputs"):
        compare_module(Wrapped(), xml, other, n_queries=64, where="the fit in memory")
