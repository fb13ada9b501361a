"""A seeded family of balance robots (MJCF) of bemlearn's class, each with its ground truth (issue 28).

``generate_robot(seed, index)`` → ``(xml_text, truth)``: one MuJoCo model with exactly one passive hinge
(q_u, a pole that is balanced upright) and 1–3 actuated joints, and a JSON-able dict of what was drawn and
of its oracle (:mod:`bemlearn.bench.family.oracle`).  The draw uses ``numpy.random.default_rng([seed, index])``
only, so the same (seed, index) gives the same bytes.

What varies (what real files vary):

* topology (``index mod 6``): cart-pole (slide + hinge); rotary arm + pendulum (Furuta-like); reaction-wheel
  pendulum (actuated wheel, passive pendulum); pendubot (actuated shoulder, passive elbow); two-link arm
  (two actuated hinges) with a pole at its tip; x-y cart (two parallel slides; half of them on a third
  actuated turntable) with a pole — m = 1, 2 or 3 actuated joints, hinges and slides, serial and parallel;
* the zero of q_u: the pole modelled upright, hanging or tilted (body ``axisangle`` or a downward
  ``fromto``) and a joint ``ref`` of 0, π or another angle — the upright q_u* = ref − tilt is then 0, π or
  elsewhere, by ``ref``, by geometry or both;
* ``compiler angle`` degree or radian; time step 0.5–20 ms (log-uniform); integrator Euler / implicitfast / RK4;
* actuators ``motor`` / ``position`` (kp, kv) / ``velocity`` (kv) / ``general`` (a DC motor: fixed gain,
  back-EMF bias) with gear, ctrlrange and, for some, forcerange; damping, armature and (30 %) frictionloss on
  the actuated joints; joint ranges; ``<default>`` classes; explicit ``<inertial>`` or geometric inertia.

Sizes are physical draws (masses, lengths); the actuator limits are then sized from the oracle's own demand
along the design region (``mj_inverse``, :meth:`Oracle.static_demand`): most robots get 1.5–4× the demand,
about one in six deliberately 0.3–0.7× (or a cart rail of a few cm), and the oracle's ``holdable`` says which
can be held (checked, not assumed).
"""

from __future__ import annotations

import math

import numpy as np

from bemlearn.bench.family.oracle import Oracle, mass_matrix, wrap_angle
from bemlearn.errors import ArgumentError

__all__ = ["TOPOLOGIES", "ACTUATOR_KINDS", "CONVENTION_KEYS", "generate_robot", "robot_name"]

TOPOLOGIES = ("cartpole", "rotary_arm", "reaction_wheel", "pendubot", "arm2_pole", "xy_cart")
ACTUATOR_KINDS = ("motor", "position", "velocity", "general")
G = 9.81


def robot_name(seed: int, index: int) -> str:
    """File stem of robot ``index`` of family ``seed``."""
    return f"fam{seed}_{index:03d}"


def _f(x: float) -> str:
    """A number as the file writes it (6 significant digits, deterministic)."""
    v = float(f"{x:.6g}")
    return "0" if v == 0 else f"{v:.6g}"


class _Draw:
    """Everything drawn for one robot (physical sizes first, the file's conventions after)."""

    def __init__(self, seed: int, index: int):
        rng = np.random.default_rng([seed, index])
        self.rng = rng
        self.topology = TOPOLOGIES[index % len(TOPOLOGIES)]
        self.degrees = bool(rng.random() < 0.5)
        self.timestep = float(f"{math.exp(rng.uniform(math.log(5e-4), math.log(2e-2))):.2g}")
        self.integrator = str(rng.choice(["Euler", "Euler", "implicitfast", "RK4"]))
        self.defaults = bool(rng.random() < 0.5)
        self.explicit_inertia = bool(rng.random() < 0.5)
        # the zero of q_u: geometry tilt of the pole and joint ref
        conv = int(rng.integers(0, 6))
        other = float(rng.choice([-1, 1]) * rng.uniform(0.3, 2.5))
        self.tilt, self.ref = [(0.0, 0.0), (math.pi, 0.0), (0.0, math.pi), (math.pi, math.pi), (other, 0.0), (0.0, other)][conv]
        self.hanging_by_fromto = bool(self.tilt == math.pi and rng.random() < 0.5)
        self.qu_range = float(rng.uniform(0.5, 1.2)) if rng.random() < 0.3 else None
        self.friction = bool(rng.random() < 0.3)
        self.feasible = bool(rng.random() >= 0.17)
        self.infeasible_how = str(rng.choice(["ctrl", "force", "rail"])) if not self.feasible else ""
        m = {"cartpole": 1, "rotary_arm": 1, "reaction_wheel": 1, "pendubot": 1, "arm2_pole": 2, "xy_cart": 2}[self.topology]
        self.turntable = bool(self.topology == "xy_cart" and rng.random() < 0.5)
        m += int(self.turntable)
        self.m = m
        kinds = list(ACTUATOR_KINDS) if self.topology != "reaction_wheel" else ["motor", "velocity", "general"]
        one = str(rng.choice(kinds))
        self.kinds = [one if rng.random() < 0.7 else str(rng.choice(kinds)) for _ in range(m)]
        self.forcerange = [bool(rng.random() < (0.3 if k == "motor" else 0.6)) for k in self.kinds]
        self.margins = [float(rng.uniform(1.5, 4.0)) for _ in range(m)]
        self.force_margins = [float(rng.uniform(1.5, 4.0)) for _ in range(m)]
        self.ctrl_half = [float(rng.choice([1.0, 1.0, 5.0, 10.0, 12.0, 24.0])) for _ in range(m)]
        self.servo_speed = [float(rng.uniform(3.0, 8.0)) for _ in range(m)]
        self.servo_zeta = [float(rng.choice([0.0, rng.uniform(0.3, 1.0)])) for _ in range(m)]
        self.emf_share = [float(rng.uniform(0.1, 0.5)) for _ in range(m)]
        self.dc_gain = [float(rng.uniform(0.5, 5.0)) for _ in range(m)]
        self.damping_share = [float(rng.uniform(0.0, 0.3)) for _ in range(m)]
        self.armature_share = [float(rng.uniform(0.05, 0.5)) if rng.random() < 0.4 else 0.0 for _ in range(m)]
        self.friction_share = [float(rng.uniform(0.03, 0.15)) for _ in range(m)]
        self.pole_damping = float(rng.uniform(0.0, 2e-3))
        self.sizes = self._sizes(rng)

    def _sizes(self, rng) -> dict:
        u = rng.uniform
        t = self.topology
        if t == "cartpole":
            return {"M": u(0.3, 3.0), "m": u(0.05, 0.5), "L": u(0.2, 1.0), "rail": u(0.3, 1.2)}
        if t == "rotary_arm":
            return {"ma": u(0.05, 0.4), "La": u(0.08, 0.3), "m": u(0.02, 0.3), "L": u(0.1, 0.4), "h": u(0.1, 0.3),
                    "arm_range": u(1.5, 3.0) if rng.random() < 0.5 else None}
        if t == "reaction_wheel":
            return {"m": u(0.1, 1.0), "L": u(0.1, 0.4), "mw": u(0.1, 0.5), "rw": u(0.05, 0.12)}
        if t == "pendubot":
            return {"m1": u(0.1, 1.0), "L1": u(0.15, 0.5), "m": u(0.05, 0.5), "L": u(0.15, 0.5),
                    "sh_range": u(0.6, 1.5) if rng.random() < 0.7 else None}
        if t == "arm2_pole":
            return {"m1": u(0.2, 1.0), "L1": u(0.15, 0.4), "m2": u(0.1, 0.6), "L2": u(0.15, 0.4), "m": u(0.03, 0.3),
                    "L": u(0.2, 0.6), "r1": u(0.8, 1.6), "r2": u(0.8, 1.6)}
        return {"Mx": u(0.5, 3.0), "My": u(0.2, 1.0), "m": u(0.05, 0.4), "L": u(0.2, 0.8), "xr": u(0.3, 1.0),
                "yr": u(0.2, 0.6), "tr": u(1.0, 3.0) if rng.random() < 0.5 else None, "Mt": u(0.05, 0.3)}


class _Writer:
    """MJCF text of a draw, with the actuated joints' damping/armature/friction and actuators given."""

    def __init__(self, draw: _Draw, seed: int, index: int):
        self.d = draw
        self.name = robot_name(seed, index)

    def ang(self, rad: float) -> str:
        """An angle in the file's unit, to full precision (q_u* = ref − tilt is exact by construction)."""
        v = math.degrees(rad) if self.d.degrees else rad
        return "0" if v == 0 else f"{v:.15g}"

    def link(self, name: str, length: float, mass: float, radius: float, axis: str = "z", sign: float = 1.0, rgba: str = "") -> str:
        """A rod from the body origin along ±``axis`` (geom, and an explicit inertial when drawn so)."""
        v = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}[axis]
        end = " ".join(_f(sign * length * c) for c in v)
        col = f' rgba="{rgba}"' if rgba else ""
        if self.d.explicit_inertia:
            c = " ".join(_f(sign * 0.5 * length * k) for k in v)
            ip = mass * (length**2 / 12 + radius**2 / 4)
            ia = mass * radius**2 / 2
            diag = " ".join(_f(ia if k else ip) for k in v)
            return (f'<inertial pos="{c}" mass="{_f(mass)}" diaginertia="{diag}"/>\n'
                    f'<geom name="{name}" type="capsule" fromto="0 0 0 {end}" size="{_f(radius)}"{col}/>')
        return f'<geom name="{name}" type="capsule" fromto="0 0 0 {end}" size="{_f(radius)}" mass="{_f(mass)}"{col}/>'

    def box(self, name: str, half: tuple[float, float, float], mass: float) -> str:
        hs = " ".join(_f(h) for h in half)
        if self.d.explicit_inertia:
            a, b, c = half
            diag = " ".join(_f(mass / 3 * (p * p + q * q)) for p, q in ((b, c), (a, c), (a, b)))
            return f'<inertial pos="0 0 0" mass="{_f(mass)}" diaginertia="{diag}"/>\n<geom name="{name}" type="box" size="{hs}"/>'
        return f'<geom name="{name}" type="box" size="{hs}" mass="{_f(mass)}"/>'

    def wheel(self, name: str, mass: float, r: float, axis: str) -> str:
        width = 0.01
        v = {"x": (1, 0, 0), "y": (0, 1, 0)}[axis]
        ft = " ".join(_f(-width / 2 * k) for k in v) + " " + " ".join(_f(width / 2 * k) for k in v)
        if self.d.explicit_inertia:
            ia, ip = mass * r * r / 2, mass * (3 * r * r + width**2) / 12
            diag = " ".join(_f(ia if k else ip) for k in v)
            return f'<inertial pos="0 0 0" mass="{_f(mass)}" diaginertia="{diag}"/>\n<geom name="{name}" type="cylinder" fromto="{ft}" size="{_f(r)}"/>'
        return f'<geom name="{name}" type="cylinder" fromto="{ft}" size="{_f(r)}" mass="{_f(mass)}"/>'

    def joint(self, name: str, kind: str, axis: str, j: int | None, params: dict, rng_: tuple[float, float] | None = None,
              ref: float = 0.0) -> str:
        """A joint; actuated ones (j = their index) carry ``params['damping'|'armature'|'frictionloss'][j]``."""
        attrs = [f'name="{name}"', f'type="{kind}"', f'axis="{axis}"']
        if self.d.defaults:
            attrs.append(f'class="{"drive" if j is not None else "passive"}"')
        if j is not None:  # joint 0's values are the drive class's (when there is one); others override
            for key in ("damping", "armature", "frictionloss"):
                val = params[key][j]
                if (val > 0 and not self.d.defaults) or (self.d.defaults and j > 0 and _f(val) != _f(params[key][0])):
                    attrs.append(f'{key}="{_f(val)}"')
        elif not self.d.defaults and self.d.pole_damping > 0:
            attrs.append(f'damping="{_f(self.d.pole_damping)}"')
        if ref != 0.0:
            attrs.append(f'ref="{self.ang(ref)}"')
        if rng_ is not None:
            lo, hi = rng_
            val = f"{self.ang(lo)} {self.ang(hi)}" if kind == "hinge" else f"{_f(lo)} {_f(hi)}"
            attrs.append(f'range="{val}"')
        return "<joint " + " ".join(attrs) + "/>"

    def pole_frame(self) -> str:
        """The pole body's orientation attribute: a tilt about the pole's hinge axis (y, or x for the Furuta)."""
        if self.d.tilt == 0.0 or self.d.hanging_by_fromto:
            return ""
        ax = "1 0 0" if self.d.topology in ("rotary_arm", "reaction_wheel") else "0 1 0"
        return f' axisangle="{ax} {self.ang(self.d.tilt)}"'

    def pole_sign(self) -> float:
        return -1.0 if self.d.hanging_by_fromto else 1.0

    def qu_range(self) -> tuple[float, float] | None:
        if self.d.qu_range is None:
            return None
        q = float(wrap_angle(self.d.ref - self.d.tilt))
        return (q - self.d.qu_range, q + self.d.qu_range)

    def body(self, params: dict) -> str:
        d, s, t = self.d, self.d.sizes, self.d.topology
        J = self.joint
        pj = lambda axis: J("pole", "hinge", axis, None, params, self.qu_range(), d.ref)  # noqa: E731
        pole = lambda axis="z": self.link("pole", s["L"], s["m"], 0.01, "z", self.pole_sign(), "0.8 0.3 0.2 1")  # noqa: E731
        if t == "cartpole":
            rail = s["rail"] if d.infeasible_how != "rail" else 0.03
            return (f'<body name="cart" pos="0 0 0">\n{J("cart", "slide", "1 0 0", 0, params, (-rail, rail))}\n'
                    f'{self.box("cart", (0.1, 0.06, 0.03), s["M"])}\n'
                    f'<body name="pole" pos="0 0 0.03"{self.pole_frame()}>\n{pj("0 1 0")}\n{pole()}\n</body>\n</body>')
        if t == "rotary_arm":
            ar = (-s["arm_range"], s["arm_range"]) if s["arm_range"] else None
            return (f'<body name="arm" pos="0 0 {_f(s["h"])}">\n{J("arm", "hinge", "0 0 1", 0, params, ar)}\n'
                    f'{self.link("arm", s["La"], s["ma"], 0.01, "x")}\n'
                    f'<body name="pole" pos="{_f(s["La"])} 0 0"{self.pole_frame()}>\n{pj("1 0 0")}\n{pole()}\n</body>\n</body>')
        if t == "reaction_wheel":
            return (f'<body name="pole" pos="0 0 0"{self.pole_frame()}>\n{pj("1 0 0")}\n{pole()}\n'
                    f'<body name="wheel" pos="0 0 {_f(self.pole_sign() * s["L"])}">\n{J("wheel", "hinge", "1 0 0", 0, params)}\n'
                    f'{self.wheel("wheel", s["mw"], s["rw"], "x")}\n</body>\n</body>')
        if t == "pendubot":
            sr = (-s["sh_range"], s["sh_range"]) if s["sh_range"] else None
            return (f'<body name="upper" pos="0 0 0">\n{J("shoulder", "hinge", "0 1 0", 0, params, sr)}\n'
                    f'{self.link("upper", s["L1"], s["m1"], 0.015, "z")}\n'
                    f'<body name="pole" pos="0 0 {_f(s["L1"])}"{self.pole_frame()}>\n{pj("0 1 0")}\n{pole()}\n</body>\n</body>')
        if t == "arm2_pole":
            return (f'<body name="upper" pos="0 0 0">\n{J("shoulder", "hinge", "0 1 0", 0, params, (-s["r1"], s["r1"]))}\n'
                    f'{self.link("upper", s["L1"], s["m1"], 0.015, "z")}\n'
                    f'<body name="fore" pos="0 0 {_f(s["L1"])}">\n{J("elbow", "hinge", "0 1 0", 1, params, (-s["r2"], s["r2"]))}\n'
                    f'{self.link("fore", s["L2"], s["m2"], 0.012, "z")}\n'
                    f'<body name="pole" pos="0 0 {_f(s["L2"])}"{self.pole_frame()}>\n{pj("0 1 0")}\n{pole()}\n</body>\n</body>\n</body>')
        xr = s["xr"] if d.infeasible_how != "rail" else 0.03
        inner = f'<body name="pole" pos="0 0 0.03"{self.pole_frame()}>\n{pj("0 1 0")}\n{pole()}\n</body>'
        if d.turntable:
            tr = (-s["tr"], s["tr"]) if s["tr"] else None
            inner = (f'<body name="turntable" pos="0 0 0.03">\n{J("yaw", "hinge", "0 0 1", 2, params, tr)}\n'
                     f'{self.box("turntable", (0.04, 0.04, 0.005), s["Mt"])}\n'
                     f'{inner}\n</body>')
        return (f'<body name="carriage" pos="0 0 0">\n{J("x", "slide", "1 0 0", 0, params, (-xr, xr))}\n'
                f'{self.box("carriage", (0.06, 0.3, 0.02), s["Mx"])}\n'
                f'<body name="cart" pos="0 0 0.04">\n{J("y", "slide", "0 1 0", 1, params, (-s["yr"], s["yr"]))}\n'
                f'{self.box("cart", (0.05, 0.05, 0.02), s["My"])}\n{inner}\n</body>\n</body>')

    def actuators(self, acts: list[dict] | None) -> str:
        names = self.joint_names()
        lines = []
        for j, name in enumerate(names):
            if acts is None:  # sizing pass: an unlimited motor
                lines.append(f'<motor name="{name}_act" joint="{name}"/>')
                continue
            a = acts[j]
            attrs = [f'name="{name}_act"', f'joint="{name}"']
            if a["gear"] != 1.0:
                attrs.append(f'gear="{_f(a["gear"])}"')
            kind = a["kind"]
            if kind == "position":
                attrs.append(f'kp="{_f(a["kp"])}"')
                if a["kv"] > 0:
                    attrs.append(f'kv="{_f(a["kv"])}"')
            elif kind == "velocity":
                attrs.append(f'kv="{_f(a["kv"])}"')
            elif kind == "general":
                attrs += ['gaintype="fixed"', f'gainprm="{_f(a["gain"])}"', 'biastype="affine"', f'biasprm="0 0 {_f(-a["emf"])}"']
            attrs.append(f'ctrlrange="{_f(a["ctrl"][0])} {_f(a["ctrl"][1])}"')
            if a.get("force") is not None:
                attrs.append(f'forcerange="{_f(-a["force"])} {_f(a["force"])}"')
            lines.append(f"<{kind} " + " ".join(attrs) + "/>")
        return "\n".join(lines)

    def joint_names(self) -> list[str]:
        return {"cartpole": ["cart"], "rotary_arm": ["arm"], "reaction_wheel": ["wheel"], "pendubot": ["shoulder"],
                "arm2_pole": ["shoulder", "elbow"], "xy_cart": ["x", "y"] + (["yaw"] if self.d.turntable else [])}[self.d.topology]

    def xml(self, params: dict, acts: list[dict] | None) -> str:
        d = self.d
        inert = ' inertiafromgeom="auto"' if d.explicit_inertia else ""
        head = [f'<mujoco model="{self.name}">',
                f"<!-- bemlearn family robot {self.name}: {d.topology}, generated by bemlearn.bench.family.generator -->",
                f'<compiler angle="{"degree" if d.degrees else "radian"}"{inert} autolimits="true"/>',
                f'<option timestep="{_f(d.timestep)}" integrator="{d.integrator}" gravity="0 0 -{_f(G)}"/>',
                "<default>", '<geom contype="0" conaffinity="0" rgba="0.6 0.6 0.7 1"/>']
        if d.defaults:
            drive = " ".join(f'{k}="{_f(params[k][0])}"' for k in ("damping", "armature", "frictionloss") if params[k][0] > 0)
            head += [f'<default class="drive"><joint {drive}/></default>' if drive else '<default class="drive"><joint/></default>',
                     f'<default class="passive"><joint damping="{_f(d.pole_damping)}"/></default>']
        head += ["</default>", "<worldbody>"]
        body = self.body(params)
        tail = ["</worldbody>", "<actuator>", self.actuators(acts), "</actuator>", "</mujoco>", ""]
        return "\n".join(head + [body] + tail)


def _sizing_demand(oracle: Oracle, n: int) -> dict:
    """Per actuated joint: |τ| peak, |q̇| peak and |q| peak along the oracle's design region."""
    q = oracle.design_queries(n, seed=1)
    taus = np.array([oracle.inverse(q["qa"][k], q["bem"][k], q["qda"][k], q["qdda"][k])[oracle.act_dofs] for k in range(q["qa"].shape[0])])
    return {"tau": np.abs(taus).max(axis=0), "qa": q["qa"], "qda": q["qda"], "taus": taus,
            "qa_peak": np.abs(q["qa"] - oracle.qa0).max(axis=0), "qd_peak": np.abs(q["qda"]).max(axis=0)}


def _mass_matrix_diag(oracle: Oracle) -> np.ndarray:
    import mujoco

    d = mujoco.MjData(oracle.smooth)
    d.qpos[:] = oracle.qa0_full()
    mujoco.mj_forward(oracle.smooth, d)
    return np.diag(mass_matrix(oracle.smooth, d))


def _actuators(d: _Draw, oracle: Oracle, dem: dict) -> list[dict]:
    """Actuator parameters sized from the demand (module docstring): limits = margin × what the design region needs."""
    Mdiag = _mass_matrix_diag(oracle)
    omega = oracle.scales()["omega_u"]
    acts = []
    weak = int(d.rng.integers(0, d.m)) if not d.feasible and d.infeasible_how in ("ctrl", "force") else -1
    for j, kind in enumerate(d.kinds):
        dof = oracle.act_dofs[j]
        inertia = Mdiag[dof]
        tau = dem["taus"][:, j] if dem["taus"].size else np.zeros(1)
        qa = dem["qa"][:, j] if dem["qa"].size else np.zeros(1)
        qd = dem["qda"][:, j] if dem["qda"].size else np.zeros(1)
        fl = d.friction_share[j] * float(np.abs(tau).max()) if d.friction else 0.0
        need = np.abs(tau) + fl
        margin = d.margins[j] if j != weak or d.infeasible_how != "ctrl" else float(d.rng.uniform(0.3, 0.7))
        fmargin = d.force_margins[j] if j != weak or d.infeasible_how != "force" else float(d.rng.uniform(0.3, 0.7))
        has_force = d.forcerange[j] or (j == weak and d.infeasible_how == "force")
        a: dict = {"kind": kind, "frictionloss": fl}
        if kind == "motor":
            gear = margin * float(need.max()) / d.ctrl_half[j]
            a.update(gear=gear, ctrl=(-d.ctrl_half[j], d.ctrl_half[j]))
            if has_force:
                # the force limit binds before the control limit when it is the weak one
                a["force"] = fmargin * float(need.max()) / gear
                if fmargin < 1:
                    a["ctrl"] = (-d.ctrl_half[j] * 4, d.ctrl_half[j] * 4)
            acts.append(a)
            continue
        gear = float(d.rng.choice([1.0, 1.0, float(d.rng.uniform(0.5, 3.0))]))
        L, Ld, f = gear * qa, gear * qd, np.sign(tau) * need / gear
        ws = min(d.servo_speed[j] * omega, 0.3 / d.timestep)  # a servo the time step resolves
        ieff = inertia / gear**2
        if kind == "position":
            kp = ieff * ws**2
            kv = 2 * d.servo_zeta[j] * math.sqrt(kp * ieff)
            u = L + (f + kv * Ld) / kp
            a.update(gear=gear, kp=kp, kv=kv)
        elif kind == "velocity":
            kv = ieff * ws
            u = Ld + f / kv
            a.update(gear=gear, kv=kv)
        else:
            emf = d.emf_share[j] * float(np.abs(f).max()) / max(float(np.abs(Ld).max()), 1e-6)
            g = d.dc_gain[j]
            u = (f + emf * Ld) / g
            a.update(gear=gear, gain=g, emf=emf)
        umax = margin * float(np.abs(u).max())
        a["ctrl"] = (-umax, umax)
        if has_force:
            a["force"] = fmargin * float(np.abs(f).max())
        acts.append(a)
    return acts


#: draw attributes a caller may override (the same robot written in another convention, for tests)
CONVENTION_KEYS = ("degrees", "tilt", "ref", "hanging_by_fromto", "defaults", "explicit_inertia")


def generate_robot(seed: int, index: int, *, hold_check: bool = True, conventions: dict | None = None) -> tuple[str, dict]:
    """Robot ``index`` of family ``seed``: ``(mjcf_text, truth)`` (module docstring; ``truth`` is JSON-able).

    ``conventions`` overrides how the file writes the same robot (keys :data:`CONVENTION_KEYS`: angle unit, the
    pole's modelled tilt, its joint ``ref``, a hanging pole by ``fromto``, default classes, explicit inertia); the
    random draw is unchanged.
    """
    d = _Draw(seed, index)
    for key, value in (conventions or {}).items():
        if key not in CONVENTION_KEYS:
            raise ArgumentError(f"conventions: unknown key {key!r}; expected one of {', '.join(CONVENTION_KEYS)}")
        setattr(d, key, value)
    w = _Writer(d, seed, index)
    zeros = {"damping": [0.0] * d.m, "armature": [0.0] * d.m, "frictionloss": [0.0] * d.m}
    qu_star = float(wrap_angle(d.ref - d.tilt)) + 0.0  # + 0.0: no −0.0 in the truth
    # pass 1: inertia and the upright's divergence rate, bare joints
    o1 = Oracle(w.xml(zeros, None), qu_upright=qu_star)
    Mdiag = _mass_matrix_diag(o1)
    omega = o1.scales()["omega_u"]
    params = {"damping": [d.damping_share[j] * Mdiag[o1.act_dofs[j]] * omega for j in range(d.m)],
              "armature": [d.armature_share[j] * Mdiag[o1.act_dofs[j]] for j in range(d.m)],
              "frictionloss": [0.0] * d.m}
    # pass 2: the design region's demand with damping and armature, unlimited motors
    o2 = Oracle(w.xml(params, None), qu_upright=qu_star)
    dem = _sizing_demand(o2, 300)
    acts = _actuators(d, o2, dem)
    params["frictionloss"] = [a["frictionloss"] for a in acts]
    xml = w.xml(params, acts)
    oracle = Oracle(xml, qu_upright=qu_star)
    up = oracle.check_upright()
    convention = ("0" if abs(qu_star) < 1e-9 else "pi" if abs(abs(qu_star) - math.pi) < 1e-9 else "other")
    zero_by = {(False, False): "plain", (True, False): "ref", (False, True): "geometry", (True, True): "ref+geometry"}[(d.ref != 0.0, d.tilt != 0.0)]
    kinds = sorted(set(d.kinds))
    truth: dict = {
        "name": robot_name(seed, index), "seed": seed, "index": index, "topology": d.topology,
        "actuated_joints": w.joint_names(), "unactuated_joint": "pole", "m": d.m,
        "qu_upright": qu_star, "qa_rest": oracle.qa0.tolist(),
        "features": {"actuator_kind": kinds[0] if len(kinds) == 1 else "mixed", "actuator_kinds": list(d.kinds),
                     "friction": bool(d.friction), "m": d.m, "upright_at": convention, "zero_by": zero_by,
                     "angle": "degree" if d.degrees else "radian", "timestep": d.timestep, "integrator": d.integrator,
                     "defaults": d.defaults, "explicit_inertia": d.explicit_inertia, "forcerange": any(a.get("force") is not None for a in acts),
                     "armature": any(v > 0 for v in params["armature"]), "qu_limited": d.qu_range is not None,
                     "tilt": d.tilt, "ref": d.ref, "hanging_by_fromto": d.hanging_by_fromto},
        "designed_holdable": d.feasible, "designed_infeasible_by": d.infeasible_how,
        "upright_check": up,
        "scales": oracle.scales(),
    }
    if hold_check:
        truth["hold"] = oracle.hold_check().to_json()
        truth["holdable"] = truth["hold"]["holdable"]
    return xml, truth
