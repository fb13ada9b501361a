"""Offscreen rendering of a logged run to an animated GIF.

Replays the logged joint coordinates through the MuJoCo model and renders frames with
``mujoco.Renderer``.  Needs an OpenGL backend without a display: set ``MUJOCO_GL=egl``
(works on this project's CI machines) or ``osmesa`` before Python imports mujoco.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

__all__ = ["render_gif"]


def render_gif(robot, q: np.ndarray, path: str | Path, *, rate_hz: float, fps: int = 25, seconds: float | None = 10.0,
               size: tuple[int, int] = (320, 240), distance: float = 1.1, elevation: float = -20.0, azimuth: float = 135.0) -> Path:
    """Write a GIF of coordinates ``q (T, n)`` (rad) logged at ``rate_hz``.

    Args:
        robot: a :class:`~bemlearn.robots.MujocoRobot` (its model and coordinate map are used).
        q: ``(T, n)`` coordinates in the robot's joint order.
        path: output ``.gif``.
        fps: frames per second of the animation (frames are subsampled from the log).
        seconds: only the first ``seconds`` of the log (``None``: all).
        size: ``(width, height)`` pixels.
        distance, elevation, azimuth: the free camera around the model centre (m, deg, deg).
    """
    from PIL import Image

    model = robot.model
    data = mujoco.MjData(model)
    step = max(1, int(round(rate_hz / fps)))
    last = q.shape[0] if seconds is None else min(q.shape[0], int(seconds * rate_hz))
    try:
        renderer = mujoco.Renderer(model, size[1], size[0])
    except Exception as exc:  # no OpenGL backend
        raise RuntimeError(f"offscreen rendering is unavailable ({exc}); set MUJOCO_GL=egl or MUJOCO_GL=osmesa") from exc
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.distance, cam.elevation, cam.azimuth = distance, elevation, azimuth
    Tinv = robot.Tinv.numpy()
    head = (model.vis.headlight.ambient.copy(), model.vis.headlight.diffuse.copy())
    model.vis.headlight.ambient[:] = 0.45  # brighter than MuJoCo's default for small GIFs;
    model.vis.headlight.diffuse[:] = 0.7  # restored below
    frames = []
    try:
        for k in range(0, last, step):
            data.qpos[:] = Tinv @ q[k]
            mujoco.mj_kinematics(model, data)
            cam.lookat[:] = data.geom_xpos.mean(axis=0)  # centre of the robot's geoms
            renderer.update_scene(data, camera=cam)
            frames.append(Image.fromarray(renderer.render()))
    finally:
        model.vis.headlight.ambient[:], model.vis.headlight.diffuse[:] = head
        renderer.close()
    if not frames:
        raise ValueError("render_gif: nothing to render (empty log)")
    path = Path(path)
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
    return path
