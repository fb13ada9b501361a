"""Offscreen rendering of a logged run to an animated GIF.

Replays the logged joint coordinates through the MuJoCo model and renders frames with
``mujoco.Renderer``.  The OpenGL backend is picked by :func:`require_offscreen_backend`:
``MUJOCO_GL`` if set (checked), otherwise EGL, then OSMesa, each probed in a child process
first (a backend that does not work can crash the process that tries it); when none works
the error is one line saying so.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from bemlearn.errors import DataError, EnvironmentProblem

if TYPE_CHECKING:
    from bemlearn.robots.mujoco_robot import MujocoRobot

__all__ = ["render_gif", "require_offscreen_backend", "probe_backend", "BACKENDS"]

#: Offscreen backends tried, in order, when ``MUJOCO_GL`` is not set.
BACKENDS = ("egl", "osmesa")

_PROBE = (
    "import mujoco\n"
    "r = mujoco.Renderer(mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=\"0.1\"/></worldbody></mujoco>'), 8, 8)\n"
    "assert r.render().shape == (8, 8, 3)\n"
    "r.close()\n"
)


@functools.cache
def probe_backend(name: str, *, timeout_s: float = 60.0) -> bool:
    """Whether ``MUJOCO_GL=name`` renders a frame, tried in a child Python process."""
    env = {**os.environ, "MUJOCO_GL": name}
    env.pop("PYOPENGL_PLATFORM", None)
    try:
        done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, timeout=timeout_s)
    except (subprocess.TimeoutExpired, OSError):
        return False
    return done.returncode == 0


def _use_backend(name: str) -> None:
    """Make ``mujoco.Renderer`` create its context with backend ``name`` in this process."""
    from mujoco.rendering.classic import gl_context

    if os.environ.get("MUJOCO_GL", "").lower() == name and getattr(gl_context, "GLContext", None) is not None:
        return  # mujoco was imported with this backend
    os.environ.setdefault("PYOPENGL_PLATFORM", name)
    if name == "egl":
        from mujoco.egl import GLContext
    elif name == "osmesa":
        from mujoco.osmesa import GLContext
    else:  # glfw / glx: mujoco's own choice
        return
    gl_context.GLContext = GLContext
    os.environ["MUJOCO_GL"] = name


def require_offscreen_backend() -> str:
    """Pick a working offscreen OpenGL backend and use it; returns its name.

    Raises:
        EnvironmentProblem: ``MUJOCO_GL`` names a backend that does not work here, or none
            of :data:`BACKENDS` works (one line, saying what was tried).
    """
    chosen = os.environ.get("MUJOCO_GL", "").strip().lower()
    if chosen:
        if not probe_backend(chosen):
            raise EnvironmentProblem(
                f"offscreen rendering: MUJOCO_GL={chosen} cannot render here; unset MUJOCO_GL to let bemlearn try {', '.join(BACKENDS)}"
            )
        _use_backend(chosen)
        return chosen
    for name in BACKENDS:
        if probe_backend(name):
            _use_backend(name)
            return name
    raise EnvironmentProblem(
        f"offscreen rendering: no working OpenGL backend (tried {', '.join(BACKENDS)}); install EGL (libegl1) or OSMesa, or drop --gif"
    )


def render_gif(robot: MujocoRobot, q: np.ndarray, path: str | Path, *, rate_hz: float, fps: int = 25, seconds: float | None = 10.0,
               size: tuple[int, int] = (320, 240), distance: float = 1.1, elevation: float = -20.0, azimuth: float = 135.0) -> Path:
    """Write a GIF of coordinates ``q (T, n)`` (rad / m by joint kind) logged at ``rate_hz``.

    Args:
        robot: a :class:`~bemlearn.robots.MujocoRobot` (its model and coordinate map are used).
        q: ``(T, n)`` coordinates in the robot's joint order.
        path: output ``.gif``.
        fps: frames per second of the animation (frames are subsampled from the log).
        seconds: only the first ``seconds`` of the log (``None``: all).
        size: ``(width, height)`` pixels.
        distance: the free camera's distance from the model centre (m).
        elevation: its elevation (deg).
        azimuth: its azimuth (deg).
    """
    from PIL import Image

    model = robot.model
    data = mujoco.MjData(model)
    step = max(1, int(round(rate_hz / fps)))
    last = q.shape[0] if seconds is None else min(q.shape[0], int(seconds * rate_hz))
    backend = require_offscreen_backend()
    try:
        renderer = mujoco.Renderer(model, size[1], size[0])
    except Exception as exc:  # the probe passed but this process cannot render
        raise EnvironmentProblem(f"offscreen rendering with MUJOCO_GL={backend} failed: {type(exc).__name__}: {exc}") from exc
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.distance, cam.elevation, cam.azimuth = distance, elevation, azimuth
    head = (model.vis.headlight.ambient.copy(), model.vis.headlight.diffuse.copy())
    model.vis.headlight.ambient[:] = 0.45  # brighter than MuJoCo's default for small GIFs;
    model.vis.headlight.diffuse[:] = 0.7  # restored below
    frames = []
    try:
        for k in range(0, last, step):
            data.qpos[:] = robot.state_to_mujoco(q[k])[0]
            mujoco.mj_kinematics(model, data)
            cam.lookat[:] = data.geom_xpos.mean(axis=0)  # centre of the robot's geoms
            renderer.update_scene(data, camera=cam)
            frames.append(Image.fromarray(renderer.render()))
    finally:
        model.vis.headlight.ambient[:], model.vis.headlight.diffuse[:] = head
        renderer.close()
    if not frames:
        raise DataError("render_gif: nothing to render (empty log)")
    from bemlearn.files import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
    return path
