"""Offscreen backend picked by itself, one-line failure; fig2 panels fit their own data (issue 16)."""

import os
from types import SimpleNamespace

import numpy as np
import pytest

from bemlearn.errors import EnvironmentProblem
from bemlearn.sim import render


@pytest.fixture
def fresh(monkeypatch):
    render.probe_backend.cache_clear()
    yield monkeypatch
    render.probe_backend.cache_clear()


def test_backend_is_picked_without_mujoco_gl(fresh):
    fresh.delenv("MUJOCO_GL", raising=False)
    fresh.delenv("PYOPENGL_PLATFORM", raising=False)
    works = [b for b in render.BACKENDS if render.probe_backend(b)]
    if not works:
        with pytest.raises(EnvironmentProblem) as info:
            render.require_offscreen_backend()
        assert "\n" not in str(info.value) and "tried egl, osmesa" in str(info.value)
        return
    assert render.require_offscreen_backend() == works[0]
    import mujoco

    r = mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>"), 16, 16)
    assert r.render().shape == (16, 16, 3)
    r.close()


def test_no_backend_fails_with_one_line(fresh):
    fresh.delenv("MUJOCO_GL", raising=False)
    fresh.setattr(render, "BACKENDS", ("nosuchgl",))
    with pytest.raises(EnvironmentProblem) as info:
        render.require_offscreen_backend()
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("offscreen rendering: no working OpenGL backend (tried nosuchgl)")


def test_a_broken_mujoco_gl_is_named(fresh):
    fresh.setenv("MUJOCO_GL", "nosuchgl")
    with pytest.raises(EnvironmentProblem, match=r"MUJOCO_GL=nosuchgl cannot render here; unset MUJOCO_GL"):
        render.require_offscreen_backend()
    assert os.environ["MUJOCO_GL"] == "nosuchgl"


def test_help_does_not_recommend_osmesa():
    from bemlearn.cli.main import build_parser

    text = build_parser()._subparsers._group_actions[0].choices["simulate"].format_help()
    assert "osmesa" not in text.lower()


def test_fig2_panels_fit_their_data():
    from bemlearn.sim.figures import run_figure

    t = np.arange(0, 60.0 + 1e-9, 0.01)
    res = SimpleNamespace(t=t, q=np.stack([np.sin(t), 0.01 * np.cos(t)], 1), qa_ref=np.sin(t)[:, None], qu_e=0.01 * np.cos(t),
                          u=np.zeros((t.size, 1)), metrics={"bem_source": "model"})
    for lemma in (None, {"t": np.linspace(0, 2, 50), "delta_gamma": np.zeros(50), "hdot": np.zeros(50)}):
        fig = run_figure(res, model_bem=0.01 * np.cos(t), lemma=lemma)
        ax = fig.axes
        assert ax[0].get_xlim() == pytest.approx((0.0, 60.0))
        assert ax[1].get_xlim() == pytest.approx((50.0, 60.0))  # the last 10 s fill panel (b)
        assert ax[-1].get_xlim() == pytest.approx((0.0, 60.0))
        if lemma is not None:
            assert ax[2].get_xlim() == pytest.approx((0.0, 2.0))
        import matplotlib.pyplot as plt

        plt.close(fig)
