"""Parameter-mismatch variants of any MJCF robot, built through ``mujoco.MjSpec``.

For the chosen bodies (default: every body) with mass scale s_m and length scale s_L:

    m → s_m m,   I → s_m s_L² I (principal inertia),   c → s_L c (centre of mass),
    body / joint / geom / site positions, geom sizes and ``fromto`` → s_L ·

A length scale of a body scales its own frame offset from its parent and everything it
carries.  Every body's inertial is first made explicit from the compiled model (so the
result does not depend on ``inertiafromgeom`` or geom densities) and the compiler is told
not to recompute it from geoms.  Joint ranges of slides are scaled by s_L too.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from bemlearn.errors import ArgumentError

__all__ = ["scaled_spec", "scaled_model", "scaled_robot"]


def scaled_spec(source: str | Path | mujoco.MjSpec, *, mass_scale: float = 1.0, length_scale: float = 1.0,
                bodies: Sequence[str] | None = None) -> mujoco.MjSpec:
    """An ``MjSpec`` of ``source`` (MJCF path or spec) with the chosen bodies scaled (module docstring).

    Raises:
        ValueError: non-positive scales, or a body name not in the model (listing the names).
    """
    if not (mass_scale > 0 and length_scale > 0):
        raise ArgumentError(f"scaled_spec: mass_scale and length_scale must be > 0, got {mass_scale}, {length_scale}")
    spec = mujoco.MjSpec.from_file(str(source)) if not isinstance(source, mujoco.MjSpec) else source
    model = spec.compile()
    names = [b.name for b in spec.bodies if b.name != "world"]
    if bodies is not None:
        unknown = sorted(set(bodies) - set(names))
        if unknown:
            raise ArgumentError(f"scaled_spec: unknown bodies {unknown}; the model has {names}")
    chosen = set(names if bodies is None else bodies)
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    sL, sm = length_scale, mass_scale
    for body in spec.bodies:
        if body.name == "world":
            continue
        i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body.name)
        body.explicitinertial = True
        body.fullinertia = np.array([np.nan, 0, 0, 0, 0, 0])
        body.mass = float(model.body_mass[i])
        body.ipos = model.body_ipos[i].copy()
        body.iquat = model.body_iquat[i].copy()
        body.inertia = model.body_inertia[i].copy()
        if body.name not in chosen:
            continue
        body.mass = body.mass * sm
        body.inertia = body.inertia * sm * sL**2
        body.ipos = body.ipos * sL
        body.pos = body.pos * sL
        for j in body.joints:
            j.pos = j.pos * sL
            if j.type == mujoco.mjtJoint.mjJNT_SLIDE:
                j.range = j.range * sL
        for g in body.geoms:
            g.pos = g.pos * sL
            g.size = g.size * sL
            if not np.isnan(g.fromto[0]):
                g.fromto = g.fromto * sL
        for s in body.sites:
            s.pos = s.pos * sL
    return spec


def scaled_model(source: str | Path | mujoco.MjSpec, **scales) -> mujoco.MjModel:
    """The compiled ``MjModel`` of :func:`scaled_spec` (same keyword arguments)."""
    return scaled_spec(source, **scales).compile()


def scaled_robot(path: str | Path, *, name: str | None = None, coordinates: Mapping[str, Any] | None = None, **scales):
    """A :class:`~bemlearn.robots.MujocoRobot` of the scaled model of the MJCF at ``path``; ``coordinates``: the
    config's ``coordinates:`` block the unscaled robot was loaded with (:mod:`bemlearn.robots.coordinates`)."""
    from bemlearn.robots.coordinates import coordinates_mapping, custom_entries
    from bemlearn.robots.mjcf_compile import declared_spec
    from bemlearn.robots.mujoco_robot import MujocoRobot

    spec = declared_spec(path, custom_entries(coordinates))
    return MujocoRobot(scaled_model(spec, **scales), name=name or Path(path).stem, source=f"{path} (scaled {scales})",
                       coordinates=coordinates_mapping(coordinates))
