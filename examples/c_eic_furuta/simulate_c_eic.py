"""Run the C EIC controller (eic_furuta.c + the exported bem_predictor.c) against the MuJoCo Furuta.

    python examples/c_eic_furuta/simulate_c_eic.py RUN_DIR [--duration 20] [--config configs/furuta.yaml]

exports RUN_DIR's BEM to C, compiles it with eic_furuta.c into a shared library, closes the
loop through ctypes on the simulated plant (bemlearn.sim.plant.SensedPlant: encoder, velocity
filter, zero-order hold) and prints the metrics next to the Python EIC
(bemlearn.sim.closed_loop.simulate) with the same gains, reference and sensor seed: the
resolved ``simulate`` section of the Furuta's pipeline config (400 Hz, the hand-tuned EIC
gains; :func:`simulate_config`).
"""

from __future__ import annotations

import argparse
import ctypes
import dataclasses
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bemlearn.apps.furuta.model import AnalyticFuruta, FurutaParameters
from bemlearn.export.c_build import STRICT_FLAGS, compile_shared
from bemlearn.pipeline.resolve import load_pipeline_config
from bemlearn.robots import load
from bemlearn.sim.closed_loop import SimulateConfig
from bemlearn.sim.plant import SensedPlant

HERE = Path(__file__).resolve().parent
#: The Furuta's pipeline config (its ``simulate`` section: rate, fall window, hand-tuned EIC gains, reference).
FURUTA_CONFIG = HERE.parents[1] / "configs" / "furuta.yaml"


def simulate_config(predictor: Path, *, duration_s: float, config: Path = FURUTA_CONFIG) -> SimulateConfig:
    """The resolved ``simulate`` section of ``config`` with the TorchScript ``predictor`` and ``duration_s`` (s)."""
    sim = load_pipeline_config(config).simulate
    return dataclasses.replace(sim, duration_s=duration_s, predictor=str(predictor))


class Params(ctypes.Structure):
    _fields_ = [(n, ctypes.c_double) for n in ("Daa0", "sin2", "cos2", "mLl", "Duu", "mgl", "B_r", "B_p", "k_u", "b_emf", "V_max")]


class Gains(ctypes.Structure):
    _fields_ = [("kp_a", ctypes.c_double), ("kd_a", ctypes.c_double), ("kp_u", ctypes.c_double),
                ("kd_u", ctypes.c_double), ("deriv_step", ctypes.c_double), ("momentum_correction", ctypes.c_int)]


class Reference(ctypes.Structure):
    _fields_ = [("n", ctypes.c_int), ("amplitude", ctypes.c_double * 8), ("frequency_hz", ctypes.c_double * 8),
                ("phase", ctypes.c_double * 8), ("offset", ctypes.c_double)]


class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_double) for n in ("alpha_e", "alphad_e", "alphadd_e", "v_ext", "v_u", "tau")]


def build(bem_c_dir: Path, out: Path) -> Path:
    """Compile eic_furuta.c with ``bem_c_dir``/bem_predictor.c into the shared library ``out``."""
    return compile_shared([HERE / "eic_furuta.c", bem_c_dir / "bem_predictor.c"], out,
                          flags=(*STRICT_FLAGS, "-O2", f"-I{bem_c_dir}", f"-I{HERE}"))


def furuta_params(p: FurutaParameters | None = None) -> Params:
    """The controller's nominal model: the rigid-body rows of AnalyticFuruta (default: the shipped parameters)."""
    p = p if p is not None else FurutaParameters()
    a = AnalyticFuruta(p)
    return Params(a._Daa0, a._sin2, a._cos2, a._mLl, a._Duu, a._mgl, p.B_r, p.B_p, p.k_u, p.b_emf, p.V_max)


@dataclass(frozen=True)
class CRun:
    """Logs ``(T,)`` at the control rate (θ, α true, rad; θ_d; u, V) and the metrics of ``simulate``."""

    t: np.ndarray
    theta: np.ndarray
    alpha: np.ndarray
    theta_ref: np.ndarray
    u: np.ndarray
    fell: bool
    tracking_rmse: float
    alpha_max: float


def run(lib_path: Path, config: SimulateConfig) -> CRun:
    """Close the loop of ``simulate`` (same plant, sensor, start, metrics) with the C controller."""
    lib = ctypes.CDLL(str(lib_path))
    cmd = lib.eic_furuta_command
    cmd.restype = ctypes.c_double
    cmd.argtypes = [ctypes.POINTER(Params), ctypes.POINTER(Gains), ctypes.POINTER(Reference), ctypes.c_double,
                    ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_double), ctypes.POINTER(Info)]
    g = config.gains
    gains = Gains(g.kp_a, g.kd_a, g.kp_u, g.kd_u, g.deriv_step, int(g.momentum_correction))
    rc = config.reference
    ref = Reference(len(rc.amplitudes), (ctypes.c_double * 8)(*rc.amplitudes), (ctypes.c_double * 8)(*rc.frequencies_hz),
                    (ctypes.c_double * 8)(*rc.phases), rc.offset)
    params = furuta_params()
    reference = rc.build(1)
    plant = load("furuta")
    sensed = SensedPlant(plant, rate_hz=config.rate_hz, sensor=config.sensor, rng=np.random.default_rng(config.seed), where="c_eic",
                         timestep=config.physics_timestep)
    q0, qd0 = np.zeros(2), np.zeros(2)
    q0[0] = reference.derivative(np.array([0.0]), 0).numpy()[0, 0]
    q0[1] = plant.qu_nominal + config.initial_qu
    qd0[0] = reference.derivative(np.array([0.0]), 1).numpy()[0, 0]
    sensed.reset(q0, qd0)
    steps = int(round(config.duration_s * config.rate_hz))
    q_log, u_log = np.empty((steps, 2)), np.empty(steps)
    y_c, v_c, info = (ctypes.c_double * 2)(), (ctypes.c_double * 2)(), Info()
    k, fell = steps, False
    for tick in range(steps):
        q_true = sensed.true_q()
        if abs(q_true[1] - plant.qu_nominal) > config.fall_window:
            k, fell = tick, True
            break
        y, v = sensed.measure(q_true)
        y_c[:], v_c[:] = y, v
        u = cmd(params, gains, ref, tick * sensed.dt, y_c, v_c, info)
        sensed.apply(np.array([u]))
        q_log[tick], u_log[tick] = q_true, u
    t = np.arange(k) * sensed.dt
    theta_ref = reference.evaluate(t)[0][:, 0]
    mask = t >= config.warmup_s
    err = q_log[:k, 0][mask] - theta_ref[mask]
    return CRun(t, q_log[:k, 0], q_log[:k, 1], theta_ref, u_log[:k], fell,
                float(np.sqrt(np.mean(err**2))) if mask.any() else float("nan"), float(np.abs(q_log[:k, 1]).max()))


def main() -> None:
    from bemlearn.export import export_c, export_run
    from bemlearn.sim.closed_loop import simulate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--config", type=Path, default=FURUTA_CONFIG, help="pipeline config whose simulate section is used")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        export_c(args.run_dir, tmp)
        pt = export_run(args.run_dir, out=tmp / "bem_predictor.pt")[0]
        config = simulate_config(pt, duration_s=args.duration, config=args.config)
        c = run(build(tmp, tmp / "libeic.so"), config)
        py = simulate(load("furuta"), config, progress=False)
    print(f"C EIC:      fell={c.fell}  tracking RMSE {c.tracking_rmse:.4f} rad  max|alpha| {c.alpha_max:.4f} rad")
    print(f"Python EIC: fell={py.fell}  tracking RMSE {py.metrics['tracking_rmse']:.4f} rad  "
          f"max|alpha| {py.metrics['qu_max']:.4f} rad")


if __name__ == "__main__":
    main()
