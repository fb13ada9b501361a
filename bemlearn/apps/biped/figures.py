"""Fig. 4 / Fig. 5 equivalents of the biped's GPDM study (Section IV-B)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["fig4", "fig5"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def fig4(r, model_bem, steady, chi, chi_hat, path: Path, *, window_s: float = 3.0) -> None:
    """Fig. 4 layout: torso q1 with μ(x_0^e) and the model BEM; hips; knees; χ and χ̂ (first ``window_s`` of steady walking)."""
    plt = _plt()
    n = min(len(steady), int(window_s * r.config.rate_hz))
    k = steady[:n]
    t = r.t[k]
    fig, ax = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    ax[0].plot(t, r.q_meas[k, 0], "k", lw=1.2, label="torso $q_1$")
    ax[0].plot(t, r.qu_e[k], "C1", lw=1.2, label="learned BEM $\\mu(x_0^e)$ (eq. 14, in the loop)")
    ax[0].plot(t, model_bem[k], "C2--", lw=1, label="model-based BEM $q_1^e$ (eq. 9)")
    for a, cols, name in ((ax[1], (1, 3), "hip"), (ax[2], (2, 4), "knee")):
        for j, col in enumerate(cols):
            a.plot(t, r.q_meas[k, col], f"C{j}", lw=1, label=f"$q_{col + 1}$ ({name} {j + 1})")
        a.set_ylabel("rad")
        a.legend(loc="upper right", fontsize=8)
    ax[3].plot(t, chi[:n], "k", lw=1.2, label="$\\chi = c(q - \\bar q)$")
    ax[3].plot(t, chi_hat[:n], "C1--", lw=1.2, label="$\\hat\\chi = c([q_a, \\mu(x_0^e)] - \\bar q)$")
    ax[0].set_ylabel("rad")
    ax[3].set_ylabel("latent")
    ax[3].set_xlabel("t (s)")
    for a in (ax[0], ax[3]):
        a.legend(loc="upper right", fontsize=8)
    ax[0].set_title("Biped walking with the learned torso BEM in the loop (cf. paper Fig. 4)")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def fig5(human: np.ndarray, robot: np.ndarray, chi_h: np.ndarray, chi_hat: np.ndarray, path: Path) -> None:
    """Fig. 5 layout over the step phase: trunk, hips, knees (human mapped vs robot), χ (human) and χ̂ (robot)."""
    plt = _plt()
    s = (np.arange(len(human)) + 0.5) / len(human)
    fig, ax = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    ax[0].plot(s, human[:, 0], "k--", label="human trunk")
    ax[0].plot(s, robot[:, 0], "k", label="robot torso $q_1$")
    ax[0].plot(s, robot[:, 5], "C1", label="robot learned BEM $\\mu(x_0^e)$")
    for a, cols, name in ((ax[1], (1, 3), "hip"), (ax[2], (2, 4), "knee")):
        for j, col in enumerate(cols):
            leg = ("stance", "swing")[j]
            a.plot(s, human[:, col], f"C{j}--", label=f"human {leg} {name} (mapped)")
            a.plot(s, robot[:, col], f"C{j}", label=f"robot {leg} {name}")
    ax[3].plot(s, chi_h, "k", label="$\\chi$ (human, its GPDM)")
    ax[3].plot(s, chi_hat, "C1--", label="$\\hat\\chi$ (robot: $c_h[q_a, \\mu(x_0^e)]$)")
    for a in ax:
        a.legend(loc="best", fontsize=7)
    for a in ax[:3]:
        a.set_ylabel("rad")
    ax[3].set_ylabel("latent")
    ax[3].set_xlabel("step phase (time since touchdown / step time)")
    ax[0].set_title("Human gait transferred to the biped (cf. paper Fig. 5), step-phase averages")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def _save(fig, path: Path) -> None:
    """``fig`` as a PNG at ``path``, written atomically."""
    from bemlearn.files import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
