"""The biped's GPDM study (Section III-C, eq. 16–17): GPDM fits of the robot's and the human gait, χ vs χ̂.

* :func:`fit_gpdm_logged` — a GPDM fit with TensorBoard logging of every objective term,
  writing c, latents and metrics (used by ``bemlearn gpdm`` too).
* :func:`human_gait_sequences` — the human steps as 5-joint sequences in robot ranges.
* :func:`latent_study` — with the walks that had the learned BEM in the loop:

      χ = c·(q − q̄),    χ̂ = c·([q_a, μ(x_0^e)] − q̄)     (Section III-C; q̄ the GPDM's joint mean)

  Fig. 4: the robot's own GPDM (c from its steps) on its steady steps, in time.
  Fig. 5: the human GPDM's c applied to the robot walking the human-derived gait; human
  χ and robot χ̂ are averaged in bins of the step phase (time since touchdown over step
  time) because the human and the robot walk at different cadences.
"""

from __future__ import annotations

import itertools
import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bemlearn.apps.biped.figures import fig4, fig5
from bemlearn.apps.biped.human_gait import HumanGaitConfig, human_step_profile, load_human_gait
from bemlearn.errors import DataError
from bemlearn.fitting.gpdm_fit import GPDMConfig
from bemlearn.threads import torch_threads

__all__ = ["fit_gpdm_logged", "human_gait_sequences", "latent_study", "PAPER_C_ROBOT", "PAPER_C_HUMAN"]

log = logging.getLogger(__name__)

#: Gait vectors reported in the paper (Sec. IV-B), [q1 … q5], in the paper's normalization.
PAPER_C_ROBOT = (-0.82, 0.97, -0.72, -4.09, 5.91)
PAPER_C_HUMAN = (-1.47, 1.75, 1.86, -1.75, 1.95)


def fit_gpdm_logged(Q_list: list[np.ndarray], out_dir: str | Path, *, config: GPDMConfig, threads: int | None = 1,
                    progress: bool = True):
    """Fit a GPDM (modified eq. 17) with TensorBoard logging; write ``metrics.json`` and ``latents.npz``.

    Args:
        Q_list: one ``(T_i, 5)`` array per sequence, joint angles q1..q5, rad.
        out_dir: folder for ``tb/`` (every objective term and hyperparameter per evaluation),
            ``metrics.json`` (c, c̃, terms, fit time) and ``latents.npz`` (``chi`` MAP latents,
            ``projection`` c·(q − q̄), ``sequence`` index, ``q``).
        config: fit options.  threads: torch threads during the fit (restored), ``None``: unchanged.

    Returns:
        The fitted :class:`~bemlearn.models.gpdm.GPDM`.
    """
    from torch.utils.tensorboard import SummaryWriter

    from bemlearn.fitting.gpdm_fit import fit_gpdm, gpdm_metrics
    from bemlearn.models.gpdm import compare_latents

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    writer = SummaryWriter(str(out / "tb"))
    t0 = time.perf_counter()
    try:
        def log_metrics(step: int, m: dict[str, float]) -> None:
            for k, v in m.items():
                writer.add_scalar(f"gpdm/{k}", v, step)

        with torch_threads(threads):
            model = fit_gpdm(Q_list, config=config, progress=progress, callback=log_metrics)
    finally:
        writer.close()
    seconds = time.perf_counter() - t0
    Q = np.concatenate(Q_list)
    chi, proj = torch.cat(model.latents), model.project(torch.from_numpy(Q))
    metrics: dict[str, Any] = {"c": model.c.tolist(), "c_normalized": model.c_normalized.detach().tolist(),
               "q_mean": model.q_mean.tolist(), "fit_seconds": seconds, "sequences": [len(q) for q in Q_list],
               "corr_latent_projection": compare_latents(chi, proj).corr, **gpdm_metrics(model)}
    from bemlearn.files import atomic_path, atomic_write_text

    with atomic_path(out / "latents.npz") as tmp:
        np.savez(tmp, chi=chi.numpy(), projection=proj.numpy(), q=Q,
                 sequence=np.repeat(np.arange(len(Q_list)), [len(q) for q in Q_list]))
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2))   # last: its presence marks a finished fit
    log.info("GPDM: c = %s in %.1f s", np.round(metrics["c"], 3).tolist(), seconds)
    return model


def human_gait_sequences(config: HumanGaitConfig = HumanGaitConfig()) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Human steps as q = [trunk, stance hip, stance knee, swing hip, swing knee] (robot ranges), rad.

    Every right heel strike t_h and t_h + T/2 (T the mean cycle) starts a step of T/2 at the
    recording's samples; the other leg is the right one shifted by T/2 (the half-cycle
    assumption of :mod:`bemlearn.apps.biped.human_gait`), hips and knees go through the linear map
    of :func:`~bemlearn.apps.biped.human_gait.human_step_profile`, the trunk is kept.

    Returns:
        ``(sequences, phases)``: ``(T_i, 5)`` arrays and their step phases ``(T_i,)`` in [0, 1).
    """
    g = load_human_gait(config.path)
    _, _, jmap = human_step_profile(config)
    thr = config.heel_strike_threshold
    period, hs = g.cycle_period(threshold=thr), g.heel_strikes(threshold=thr)
    half = period / 2
    right = lambda t: np.stack([np.interp(t, g.t, g.hip), np.interp(t, g.t, g.knee)], 1)  # noqa: E731
    seqs, phases = [], []
    for start in np.sort(np.r_[hs, hs + half]):
        t = g.t[(g.t >= start) & (g.t < start + half)]
        left = bool(np.isclose(hs, start - half).any())  # left heel strike: the right leg swings
        lo, hi = (t - half, t) if left else (t, t + half)  # times of the stance / swing leg's angles
        if len(t) < 3 or lo[0] < g.t[0] or hi[-1] > g.t[-1]:
            continue
        qa = jmap.apply(np.c_[right(lo), right(hi)])
        seqs.append(np.c_[np.interp(t, g.t, g.trunk), qa])
        phases.append((t - start) / half)
    if not seqs:
        raise DataError(f"{g.source}: no complete human step (need a heel strike and a full cycle after it)")
    return seqs, phases




def _stance_q(result) -> np.ndarray:
    """Measured q of a walk in stance-relative order, ``(T, 5)`` rad."""
    from bemlearn.apps.biped.gait import stance_frame

    return np.stack([stance_frame(q, leg) for q, leg in zip(result.q_meas, result.stance)]) if len(result.t) else result.q_meas


def _steady_steps(result, first_step: int) -> list[slice]:
    """Tick slices of the complete steps after the first ``first_step`` ones."""
    ends = np.r_[0, result.steps + 1]
    return [slice(int(a), int(b)) for a, b in itertools.pairwise(ends)][first_step:]


def _binned(phase: np.ndarray, values: np.ndarray, bins: int) -> np.ndarray:
    """Mean of ``values (N, ...)`` in ``bins`` equal bins of ``phase (N,)`` ∈ [0, 1) (NaN where empty)."""
    idx = np.clip((phase * bins).astype(int), 0, bins - 1)
    out = np.full((bins, *values.shape[1:]), np.nan)
    for b in range(bins):
        if (idx == b).any():
            out[b] = values[idx == b].mean(0)
    return out


def _chis(gpdm, q: np.ndarray, mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """χ = c·(q − q̄) and χ̂ = c·([q_a, μ] − q̄) for ``q (T, 5)`` rad and ``mu (T,)`` rad."""
    from bemlearn.models.gpdm import reconstruct_latent

    chi = gpdm.project(torch.from_numpy(q)).numpy()
    chi_hat = reconstruct_latent(torch.from_numpy(q[:, 1:]), torch.from_numpy(mu), unactuated_index=0, c=gpdm.c,
                                 q_offset=gpdm.q_mean).numpy()
    return chi, chi_hat


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.corrcoef(a[ok], b[ok])[0, 1])


def latent_study(loop: dict, robot_gpdm, human_gpdm, human_Q: list[np.ndarray], human_phase: list[np.ndarray], *,
                 first_step: int, bins: int, out: str | Path) -> dict:
    """χ vs χ̂ for the robot (Fig. 4) and the human gait (Fig. 5); writes both PNGs into ``out``.

    Args:
        loop: ``{gait: WalkResult}`` walks with the learned BEM in the loop (``qu_e`` = μ(x_0^e)).
        robot_gpdm, human_gpdm: fitted :class:`~bemlearn.models.gpdm.GPDM` s.
        human_Q, human_phase: :func:`human_gait_sequences`.
        first_step: start-up steps left out.  bins: step-phase bins for Fig. 5.

    Returns:
        Numbers for the report: c vectors, |corr(χ, χ̂)|, RMSE(χ − χ̂), in-loop learned vs
        model BEM RMSE per gait (rad).
    """
    from bemlearn.control.bem_sources import ModelBEM
    from bemlearn.robots import load
    from bemlearn.robots.protocol import ControlRobot

    out = Path(out)
    nominal = load("biped")
    assert isinstance(nominal, ControlRobot)
    model = ModelBEM(nominal)
    res: dict = {"c_robot": robot_gpdm.c.tolist(), "c_human": human_gpdm.c.tolist(), "loop_bem": {}}
    curves = {}
    for gait, r in loop.items():
        steady = np.concatenate([np.zeros(0, dtype=int)] + [np.arange(s.start, s.stop) for s in _steady_steps(r, first_step)]).astype(int)
        model_bem = model(r.bem_x) if len(r.t) else np.zeros(0)
        e = (r.qu_e - model_bem)[steady]
        res["loop_bem"][gait] = {"rmse_learned_vs_model": float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")}
        curves[gait] = (r, _stance_q(r), model_bem, steady)
    if "default" in curves:
        r, q, model_bem, steady = curves["default"]
        chi, chi_hat = _chis(robot_gpdm, q[steady], r.qu_e[steady])
        res["robot"] = {"corr": _corr(chi, chi_hat), "rmse": float(np.sqrt(np.mean((chi - chi_hat) ** 2))),
                        "chi_std": float(chi.std())}
        fig4(r, model_bem, steady, chi, chi_hat, out / "fig4_robot_walking.png")
    if "human" in curves:
        r, q, _, _ = curves["human"]
        ph = np.concatenate([np.arange(s.stop - s.start) / (s.stop - s.start) for s in _steady_steps(r, first_step)])
        rows = np.concatenate([np.arange(s.start, s.stop) for s in _steady_steps(r, first_step)])
        chi_r, chi_hat = _chis(human_gpdm, q[rows], r.qu_e[rows])
        Qh, Ph = np.concatenate(human_Q), np.concatenate(human_phase)
        chi_h = human_gpdm.project(torch.from_numpy(Qh)).numpy()
        b_h, b_hat, b_r = _binned(Ph, chi_h, bins), _binned(ph, chi_hat, bins), _binned(ph, chi_r, bins)
        res["human"] = {"corr_phase_binned": _corr(b_h, b_hat), "corr_robot_q_vs_human": _corr(b_h, b_r),
                        "rmse_phase_binned": float(np.sqrt(np.nanmean((b_h - b_hat) ** 2))),
                        "human_trunk_mean": float(Qh[:, 0].mean()), "robot_torso_mean": float(q[rows, 0].mean()),
                        "robot_bem_mean": float(r.qu_e[rows].mean())}
        fig5(_binned(Ph, Qh, bins), _binned(ph, np.c_[q[rows], r.qu_e[rows]], bins), b_h, b_hat, out / "fig5_human_gait.png")
    return res


