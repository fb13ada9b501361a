"""The pipeline keys the robot's model determines, as dotted config keys with how each was derived.

:func:`derive_pipeline_values` turns the model-derived values of :mod:`bemlearn.pipeline.derive`
into ``{"collect.rate_hz": (value, note), ...}`` leaves for
:func:`~bemlearn.pipeline.resolve.resolve_pipeline_config`, which fills in only the keys the
config does not give.  It is the one assembly of the derived defaults: ``bemlearn run``,
``config show``, ``bench robots`` and the tests all go through it.  Values that depend on each
other are derived consistently with what the config *does* give: a given control rate is used for
the excitation LQR, the velocity filter and the EIC gains, and the closed loop runs at the
collection's rate unless told otherwise.  A group of keys that come from one derivation (the LQR
gains, the sensor, the excitation's sines, the held-out references, the EIC gains, the closed-loop
reference) is derived only when the config leaves at least one of them out.
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, Any

from bemlearn.config import to_dict
from bemlearn.pipeline import derive
from bemlearn.pipeline.derive import Derived, RateChoice, control_rate

if TYPE_CHECKING:
    from bemlearn.pipeline.config import PipelineConfig

__all__ = ["DERIVED_KEYS", "MODEL_DERIVED_KEYS", "derive_model_values", "derive_pipeline_values"]

_COLLECT = ("rate_hz", "physics_timestep", "gains", "gain_scale", "fall_window", "input_units", "sensor", "n_sines",
            "amplitude", "frequency_hz", "initial_qa", "initial_qu", "reference_bem", "excursion")
_SIMULATE = ("rate_hz", "physics_timestep", "gains", "reference", "fall_window", "sensor")
_SENSOR = ("counts_per_rev", "noise_std", "velocity_cutoff", "m_per_count")  # the leaves of derive.sensor
_SIGNALS = ("n_sines", "amplitude", "frequency_hz")
_DIRECTIONS = ("reference_bem", "excursion")  # with m ≥ 2 also collect.amplitude (derive.excitation_directions)
_EVALUATE = ("n_sines", "amplitude_max", "amplitude_min", "frequency_hz")
_EIC_GAINS = ("kp_a", "kd_a", "kp_u", "kd_u")
_REFERENCE = ("amplitudes", "frequencies_hz", "phases", "offset")

#: Every config key that the robot's model derives when the config does not give it (docs/config.md).
DERIVED_KEYS: set[str] = set()

DERIVED_KEYS.update(f"collect.{k}" for k in _COLLECT if k != "sensor")
_MODEL_SENSOR = tuple(k for k in _SENSOR if k != "noise_std")  # noise_std is a plain default (0), not from the model
DERIVED_KEYS.update(f"collect.sensor.{k}" for k in _MODEL_SENSOR)
DERIVED_KEYS.update(f"simulate.{k}" for k in _SIMULATE if k not in ("gains", "reference", "sensor"))
DERIVED_KEYS.update(f"simulate.gains.{k}" for k in _EIC_GAINS)
DERIVED_KEYS.update(f"simulate.reference.{k}" for k in _REFERENCE)
DERIVED_KEYS.update(f"simulate.sensor.{k}" for k in _MODEL_SENSOR)
DERIVED_KEYS.update(f"evaluate.{k}" for k in _EVALUATE)
DERIVED_KEYS.add("train.mean")   # zero, or auto where the excitation moves each actuated direction on its own
#: The keys a model-free run's ``model:`` derives (the held-out references its learned BEM is compared along).
MODEL_DERIVED_KEYS: set[str] = {f"evaluate.{k}" for k in _EVALUATE}

def _leaves(prefix: str, value: Any, note: str, out: dict) -> None:
    value = to_dict(value)
    if isinstance(value, dict):
        for k, v in value.items():
            _leaves(f"{prefix}.{k}", v, note, out)
    else:
        out[prefix] = (value, note)


def _rate(robot, rate_hz: float | None, timestep: float | None, *, section: str = "collect"):
    """The :class:`~bemlearn.pipeline.derive.RateChoice` of a given rate (and physics step), or the derived one.

    A given rate that is not a whole number of the file's physics steps (and no given step) gets the
    largest step h' ≤ h_file with 1/(rate·h') whole; a given step must divide the rate's tick.
    """
    from bemlearn.errors import ConfigError

    if rate_hz is None:
        return control_rate(robot)
    h_file = float(robot.model.opt.timestep)
    h = float(timestep or h_file)
    n = 1.0 / (rate_hz * h)
    if abs(n - round(n)) <= 1e-6 and round(n) >= 1:
        return Derived(RateChoice(rate_hz, int(round(n)), h, timestep is not None and not math.isclose(h, h_file)),
                       f"the given {rate_hz:g} Hz")
    if timestep is not None:
        raise ConfigError(f"{section}.rate_hz = {rate_hz:g} Hz is not a whole number of the given {section}.physics_timestep {h:g} s "
                          f"({n:.4g} steps); give a step that divides 1/{rate_hz:g} s, or leave physics_timestep out "
                          "to have it derived")
    N = max(1, math.ceil(1.0 / (rate_hz * h_file) - 1e-9))
    fine = 1.0 / (rate_hz * N)
    note = (f"the given {rate_hz:g} Hz; the plant runs {N} physics step(s) of {fine:.6g} s per tick (the file's "
            f"{h_file:g} s is not a whole fraction of 1/{rate_hz:g} s)")
    return Derived(RateChoice(rate_hz, N, fine, True), note)


def derive_pipeline_values(robot, config: PipelineConfig, given: set[str] | frozenset[str] = frozenset()) -> dict[str, tuple[Any, str]]:
    """``{dotted key: (value, how it was derived)}`` for the derivable keys of ``config`` (docs/config.md): every
    key of each group the config does not give in full (module docstring).

    Args:
        robot: the config's robot (a :class:`~bemlearn.robots.MujocoRobot`; other robots derive nothing).
        config: the :class:`~bemlearn.pipeline.config.PipelineConfig` as given (its given values steer the
            derivation: see module docstring).
        given: the dotted keys the config gives (none: every key is derived from the model alone).
    """
    from bemlearn.robots import MujocoRobot

    if not isinstance(robot, MujocoRobot):
        return {}
    out: dict[str, tuple[Any, str]] = {}
    given_collect_rate = config.collect.rate_hz if _given(given, "collect.rate_hz") else None
    given_sim_rate = config.simulate.rate_hz if _given(given, "simulate.rate_hz") else given_collect_rate
    given_collect_step = config.collect.physics_timestep if _given(given, "collect.physics_timestep") else None
    crate = _rate(robot, given_collect_rate, given_collect_step)
    if _given(given, "simulate.physics_timestep"):
        srate = _rate(robot, given_sim_rate, config.simulate.physics_timestep, section="simulate")
    elif not _given(given, "simulate.rate_hz"):   # the closed loop follows the collection's rate and step
        srate = crate
    else:
        srate = _rate(robot, given_sim_rate, None, section="simulate")
    rc, rs = crate.value, srate.value

    def wanted(prefix: str, keys: tuple[str, ...]) -> bool:  # derive a group only when the config leaves one of its keys out
        return any(not _given(given, f"{prefix}.{k}") for k in keys)

    fw = derive.fall_window(robot)

    @functools.cache
    def excitation() -> dict:  # collect's sines, also the base of evaluate's references and of the closed loop's
        sig = derive.excitation_signals(robot, rc)
        value, note = dict(sig.value), sig.note
        # the trials decide, whatever set A_hi, where they play the collection that will run: m = 1 (with m ≥ 2 the
        # collection moves each direction on its own, excitation_directions, which these trials do not play yet)
        if not _given(given, "collect.amplitude") and (robot.m == 1 or value.get("effort_capped")):
            check = derive.excitation_amplitude_check(robot, _collect_for_check(robot, config, given, out, value, rc, fw.value))
            note += f"; {check.note}"
            if check.value < 1:
                value["amplitude"] = tuple(check.value * a for a in value["amplitude"])
                note += f": A × {check.value:g}"
        _leaves("collect", {k: value[k] for k in _SIGNALS}, note, out)
        return value

    _leaves("collect.rate_hz", rc.rate_hz, crate.note, out)
    _leaves("collect.physics_timestep", rc.timestep if rc.timestep_changed else None, crate.note, out)
    if wanted("collect", ("gains", "gain_scale")):
        wc_collect = config.collect.sensor.velocity_cutoff if _given(given, "collect.sensor.velocity_cutoff") else None
        gains = derive.excitation_gains(robot, rc, velocity_cutoff=wc_collect)   # its gain scale is checked with the trials' filter
        _leaves("collect.gains", gains.value["gains"], gains.note, out)
        _leaves("collect.gain_scale", gains.value["gain_scale"], gains.note, out)
    _leaves("collect.fall_window", fw.value, fw.note, out)
    units = derive.input_units(robot)
    _leaves("collect.input_units", units.value, units.note, out)
    if wanted("collect.sensor", _SENSOR):
        sen = derive.sensor(robot, rc)
        _leaves("collect.sensor", sen.value, sen.note, out)
    if wanted("collect", _SIGNALS):
        excitation()
    if wanted("collect", _DIRECTIONS):
        if _given(given, "collect.amplitude"):  # amplitudes given in the joints' units: the paper's excitation
            _leaves("collect.reference_bem", (), "collect.amplitude is given (joint units): the paper's excitation", out)
            _leaves("collect.excursion", (), "collect.amplitude is given (joint units): the paper's excitation", out)
        else:
            dirs = derive.excitation_directions(robot, rc, excitation())
            for k in ("reference_bem", "excursion", "amplitude"):
                _leaves(f"collect.{k}", dirs.value[k], dirs.note, out)
    init = derive.initial_ranges(robot)
    for k in ("initial_qa", "initial_qu"):
        _leaves(f"collect.{k}", init.value[k], init.note, out)
    if wanted("evaluate", _EVALUATE):
        ev = derive.evaluation(robot, excitation())
        _leaves("evaluate", {k: v for k, v in to_dict(ev.value).items() if k in _EVALUATE}, ev.note, out)
    _leaves("simulate.rate_hz", rs.rate_hz, srate.note + ("" if _given(given, "simulate.rate_hz") else " (the collection's rate)"), out)
    _leaves("simulate.physics_timestep", rs.timestep if rs.timestep_changed else None, srate.note, out)
    ref = derive.closed_loop_reference(robot, excitation()) if wanted("simulate.reference", _REFERENCE) else None
    if wanted("simulate.gains", _EIC_GAINS):
        wc = config.simulate.sensor.velocity_cutoff if _given(given, "simulate.sensor.velocity_cutoff") else None
        # the gains must hold the loop the run will play: the derived reference, or the given one
        played = ref.value if ref is not None else to_dict(config.simulate.reference)
        eic = derive.eic_gains(robot, rs, velocity_cutoff=wc, reference=played if all(v is not None for v in played.values()) else None)
        _leaves("simulate.gains", {k: v for k, v in to_dict(eic.value).items() if k in _EIC_GAINS}, eic.note, out)
    if ref is not None:
        _leaves("simulate.reference", ref.value, ref.note, out)
    _leaves("simulate.fall_window", fw.value, fw.note, out)
    if wanted("simulate.sensor", _SENSOR):
        sen_sim = derive.closed_loop_sensor(robot, rs)
        _leaves("simulate.sensor", sen_sim.value, sen_sim.note, out)
    if not _given(given, "train.mean"):
        ext = config.collect.excursion if _given(given, "collect.excursion") else out.get("collect.excursion", ((), ""))[0]
        _leaves("train.mean", "auto" if ext else "zero", PRIOR_MEAN_NOTE["auto" if ext else "zero"], out)
    if not _given(given, "dataset.cyclic"):
        from bemlearn.robots.cyclic import unbounded_cyclic

        left = unbounded_cyclic(robot)
        _leaves("dataset.cyclic", left, (f"{', '.join(left)}: cyclic (D and h of eq. 1 do not depend on "
                                         f"{'its' if len(left) == 1 else 'their'} position) and without a joint range: the "
                                         "position is left out of the GP inputs" if left else
                                         "no actuated coordinate is both cyclic and without a joint range"), out)
    return out


#: Why ``train.mean`` is derived as it is (:func:`derive_pipeline_values`).
PRIOR_MEAN_NOTE = {
    "auto": ("the excitation moves each actuated direction on its own (collect.excursion): the design region's 3m-dimensional "
             "box has corners beyond the data jointly, where the trend the data support carries further than the zero "
             "mean; the marginal likelihood chooses between the plane and the zero mean (eq. L2; docs/family.md)"),
    "zero": ("the paper's excitation (one actuated direction, or amplitudes given in the joints' units): eq. 11's zero "
             "mean (the plane the likelihood preferred bent an m = 1 robot's BEM at its design-box corners; docs/family.md)"),
}


def _collect_for_check(robot, config: PipelineConfig, given, out: dict, signals: dict, rate: RateChoice, fall_window: float):
    """The collection's config as it will run (given keys, else the derived ones), with ``signals``' sines."""
    import dataclasses

    from bemlearn.data.sensors import SensorConfig

    c = config.collect
    gains = c.gains if _given(given, "collect.gains") else out["collect.gains"][0]
    scale = c.gain_scale if _given(given, "collect.gain_scale") else out["collect.gain_scale"][0]
    init = derive.initial_ranges(robot).value
    sen = derive.sensor(robot, rate).value if any(not _given(given, f"collect.sensor.{k}") for k in _SENSOR) else {}
    sensor = SensorConfig(**{k: getattr(c.sensor, k) if _given(given, f"collect.sensor.{k}") else sen[k] for k in _SENSOR})
    return dataclasses.replace(
        c, rate_hz=rate.rate_hz, physics_timestep=rate.timestep if rate.timestep_changed else None, gains=gains, gain_scale=scale,
        fall_window=c.fall_window if _given(given, "collect.fall_window") else fall_window,
        initial_qa=c.initial_qa if _given(given, "collect.initial_qa") else init["initial_qa"],
        initial_qu=c.initial_qu if _given(given, "collect.initial_qu") else init["initial_qu"],
        n_sines=signals["n_sines"], amplitude=signals["amplitude"], frequency_hz=signals["frequency_hz"], sensor=sensor)


def derive_model_values(model, config: PipelineConfig, given: set[str] | frozenset[str] = frozenset()) -> dict[str, tuple[Any, str]]:
    """``{dotted key: (value, how it was derived)}`` of :data:`MODEL_DERIVED_KEYS` for a model-free run whose
    ``model:`` names ``model``: the held-out references along which the learned BEM is compared with the
    model's (``evaluate.*``), derived as for a run with ``robot:`` at the model's own control rate
    (no collection, no LQR, no closed loop: the data were recorded elsewhere).

    Args:
        model: the config's ``model:`` (a :class:`~bemlearn.robots.MujocoRobot`; other robots derive nothing).
        config: the config as given.
        given: the dotted keys the config gives; the group is derived only when one of its keys is missing.
    """
    from bemlearn.robots import MujocoRobot

    if not isinstance(model, MujocoRobot) or not any(not _given(given, f"evaluate.{k}") for k in _EVALUATE):
        return {}
    rate = control_rate(model)
    sig = derive.excitation_signals(model, rate.value)
    ev = derive.evaluation(model, sig.value)
    out: dict[str, tuple[Any, str]] = {}
    _leaves("evaluate", {k: v for k, v in to_dict(ev.value).items() if k in _EVALUATE},
            f"from model: {ev.note}", out)
    return out


def _given(given, dotted: str) -> bool:
    """Whether ``dotted`` (or a section holding it) was given."""
    return dotted in given or any(dotted.startswith(g + ".") for g in given)
