"""Figures of a closed-loop run, in the layout of the paper's Fig. 2.

(a) q_a and q_a^d; (b) q_u, the BEM used in the loop with its ±2σ band (learned
predictor) and the model-based BEM; (c) Lemma 1: ΔΓ against Ḣ_u (eq. 10); (d) the
actuator command ((c) when there is no Lemma 1 panel).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_run", "run_figure", "run_png"]


def plot_run(result, path: str | Path, *, model_bem: np.ndarray | None = None, band: tuple[np.ndarray, np.ndarray] | None = None,
             lemma: dict[str, np.ndarray] | None = None, joint_names=("q_a", "q_u"), units=("rad", "rad"),
             indices=(0, 1), input_label: str = "u") -> Path:
    """Write a PNG of a :class:`~bemlearn.sim.closed_loop.SimResult` (atomically; see :func:`run_figure`).

    Args:
        result: the run.
        path: output PNG.
        model_bem: ``(T,)`` model-based BEM at the loop's BEM inputs, in q_u's unit.
        band: ``(mean, std)`` of the learned BEM, ``(T,)`` each, in q_u's unit.
        lemma: ``{"t", "delta_gamma", "hdot"}`` arrays for panel (c).
        joint_names: names of the (first) actuated joint and of the unactuated joint.
        units: their units (rad or m, by joint kind).
        indices: their columns in ``result.q``.
        input_label: axis label of the actuator command (with its unit).
    """
    from bemlearn.files import atomic_write_bytes

    return atomic_write_bytes(path, run_png(result, model_bem=model_bem, band=band, lemma=lemma, joint_names=joint_names,
                                            units=units, indices=indices, input_label=input_label))


def run_png(result, *, model_bem: np.ndarray | None = None, band: tuple[np.ndarray, np.ndarray] | None = None,
            lemma: dict[str, np.ndarray] | None = None, joint_names=("q_a", "q_u"), units=("rad", "rad"),
            indices=(0, 1), input_label: str = "u") -> bytes:
    """The PNG bytes of :func:`plot_run`'s figure (110 dpi): a worker process returns them to its parent."""
    import io

    import matplotlib.pyplot as plt

    fig = run_figure(result, model_bem=model_bem, band=band, lemma=lemma, joint_names=joint_names, units=units,
                     indices=indices, input_label=input_label)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def run_figure(result, *, model_bem: np.ndarray | None = None, band: tuple[np.ndarray, np.ndarray] | None = None,
               lemma: dict[str, np.ndarray] | None = None, joint_names=("q_a", "q_u"), units=("rad", "rad"),
               indices=(0, 1), input_label: str = "u"):
    """The matplotlib figure of :func:`plot_run`; every panel's time axis spans its own data."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = result.t
    rows = 4 if lemma is not None else 3
    fig, ax = plt.subplots(rows, 1, figsize=(9, 2.3 * rows))  # no sharex: (b) shows the last 10 s, (c) one period
    a_name, u_name = joint_names
    a_unit, u_unit = units
    ia, iu = indices
    ax[0].plot(t, result.q[:, ia], label=f"{a_name}")
    ax[0].plot(t, result.qa_ref[:, 0], "--", label=f"{a_name}$_d$")
    ax[0].set_ylabel(f"{a_name} ({a_unit})")
    ax[0].legend(loc="upper right")
    ax[0].set_title("(a) actuated joint tracking")
    w = t >= t[-1] - 10.0 if t.size else t.astype(bool)  # last 10 s: the lines are distinguishable
    if model_bem is not None:
        ax[1].plot(t[w], model_bem[w], color="C2", lw=0.6, alpha=0.6, label="model-based BEM (at the measured inputs)")
    if band is not None:
        mean, std = band
        ax[1].fill_between(t[w], (mean - 2 * std)[w], (mean + 2 * std)[w], color="C1", alpha=0.25, label="learned BEM ±2σ (eq. 12)")
    ax[1].plot(t[w], result.qu_e[w], color="C1", lw=1.2, label=f"BEM in the loop ({result.metrics['bem_source']})")
    ax[1].plot(t[w], result.q[w, iu], color="k", lw=1.2, label=f"{u_name}")
    ax[1].set_ylabel(f"{u_name} ({u_unit})")
    ax[1].legend(loc="upper right", fontsize=7, ncol=2)
    ax[1].set_title("(b) unactuated joint and the BEM (last 10 s)")
    if t.size:
        ax[0].set_xlim(t[0], t[-1])
        ax[1].set_xlim(t[w][0], t[w][-1])
    k = 2
    if lemma is not None:
        ax[2].plot(lemma["t"], lemma["hdot"], label="$\\dot H_u$ (model)")
        if "delta_gamma_model" in lemma:
            ax[2].plot(lemma["t"], lemma["delta_gamma_model"], ":", color="k", label="ΔΓ = $\\dot H_u$ + $b_u\\dot q_u^e$ (model)")
        ax[2].plot(lemma["t"], lemma["delta_gamma"], "--", label="ΔΓ (learned, eq. 11 map only)")
        ax[2].set_ylabel("N·m")
        ax[2].set_xlabel("t (s) over one reference period")
        ax[2].legend(loc="upper right", fontsize=8)
        ax[2].set_title("(c) Lemma 1: ΔΓ vs rate of momentum")
        k = 3
    ax[k].plot(t, result.u[:, 0], lw=0.8)
    ax[k].set_ylabel(input_label)
    ax[k].set_xlabel("t (s)")
    ax[k].set_title(f"({'abcd'[k]}) actuator command")  # (c) without the Lemma 1 panel: no gap in the letters
    if t.size:
        ax[k].set_xlim(t[0], t[-1])
    if lemma is not None and len(lemma["t"]):
        ax[2].set_xlim(lemma["t"][0], lemma["t"][-1])
    fig.tight_layout()
    return fig
