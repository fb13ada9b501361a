"""A run's ``metrics.json``, typed: :class:`RunMetrics` and one record per section.

The stages write their sections (the fit, the data-only checks, the design region, the closed
loops, …) into a :class:`RunMetrics`; the verdict (:func:`~bemlearn.pipeline.verdict.judge_run`),
the report, the sweep's headline columns and the CLI read its fields, never string keys.  This
module and :mod:`bemlearn.pipeline.results` are the only places where the file's keys are spelt:

* :meth:`_Record.from_dict` reads a section (a run folder's file, or a producer's JSON-ready
  summary) into its record once;
* :meth:`_Record.as_dict` gives it back for the one writer of ``metrics.json``
  (:meth:`~bemlearn.pipeline.results.RunResult.write_metrics`, and training alone).

A record declares the keys its readers use as typed fields (``None`` where a run lacks them: an
older run folder, a model-free run); every other key of the section is kept as it came
(``extra``) and the key order is kept (``keys_``), so that ``as_dict(from_dict(doc)) == doc``
key for key and value for value: the file's content does not change with this module, and
readers of old run folders keep working.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

from bemlearn.pipeline.verdict_types import Verdict

__all__ = ["RunMetrics", "ModelCheck", "DataInfo", "DerivativeChoiceInfo", "DatasetInfo", "FitInfo", "RobotInfo",
           "DesignRegionInfo", "HeldoutBEM", "BoundViolationInfo", "DesignRegionErrorsInfo", "HeldoutTrial",
           "DataHeldout", "ResolutionInput", "Resolution", "SupportPair", "SupportInput", "Support", "SliceSummary",
           "BemSlices", "EstimatorTerm", "Uncertainty", "Equilibrium", "UnactuatedTorque", "FailedStage", "Lemma1Info",
           "LoopMetrics", "written_verdict"]

R = TypeVar("R", bound="_Record")


def _one(cls: type[_Record]) -> dict[str, Any]:
    return {"load": cls.from_dict, "dump": lambda v: v.as_dict(), "type": Mapping}


def _many(cls: type[_Record]) -> dict[str, Any]:
    return {"load": lambda v: tuple(cls.from_dict(x) for x in v), "dump": lambda v: [x.as_dict() for x in v], "type": list}


def _by_name(cls: type[_Record]) -> dict[str, Any]:
    return {"load": lambda v: {str(k): cls.from_dict(x) for k, x in v.items()},
            "dump": lambda v: {k: x.as_dict() for k, x in v.items()}, "type": Mapping}


def _key(f: dataclasses.Field) -> str:
    return f.metadata.get("key", f.name)


@dataclass(kw_only=True)
class _Record:
    """A section of ``metrics.json``: typed fields for the keys read, ``extra`` for the rest (module docstring).

    A field's JSON key is its name, or ``metadata["key"]`` (``with`` is a Python keyword); a nested
    section names its ``load`` / ``dump`` and the JSON ``type`` it must have (a value of another
    type is kept in ``extra`` as it came, and the field stays ``None``).
    """

    extra: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)
    keys_: tuple[str, ...] = field(default=(), repr=False, compare=False)

    @classmethod
    def _fields(cls) -> dict[str, dataclasses.Field]:
        return {_key(f): f for f in dataclasses.fields(cls) if f.name not in ("extra", "keys_")}

    @classmethod
    def from_dict(cls: type[R], doc: Mapping[str, Any] | None) -> R:
        """The record of section ``doc`` (``{}`` or ``None``: every field ``None``)."""
        known = cls._fields()
        kw: dict[str, Any] = {}
        extra: dict[str, Any] = {}
        for k, v in (doc or {}).items():
            f = known.get(k)
            load: Callable | None = f.metadata.get("load") if f is not None else None
            if f is None or (load is not None and v is not None and not isinstance(v, f.metadata["type"])):
                extra[k] = v
            else:
                kw[f.name] = load(v) if load is not None and v is not None else v
        return cls(**kw, extra=extra, keys_=tuple(doc or ()))

    def as_dict(self) -> dict[str, Any]:
        """The section as ``metrics.json`` holds it: the keys in the order read, then fields set since."""
        known = self._fields()
        out: dict[str, Any] = {}
        for k in (*self.keys_, *(k for k in known if k not in self.keys_)):
            if k in self.extra:
                out[k] = self.extra[k]
                continue
            f = known.get(k)
            if f is None:
                continue
            v = getattr(self, f.name)
            if v is None and k not in self.keys_:
                continue
            dump = f.metadata.get("dump")
            out[k] = dump(v) if dump is not None and v is not None else v
        return out


# ---------------------------------------------------------------- before collecting, the data, the fit


@dataclass(kw_only=True)
class ModelCheck(_Record):
    """One model check before collecting (:class:`~bemlearn.pipeline.feasibility.FeasibilityCheck`)."""

    name: str | None = None
    value: float | None = None
    limit: float | None = None
    strict: bool | None = None
    passed: bool | None = None
    severity: str | None = None
    text: str | None = None


@dataclass(kw_only=True)
class DataInfo(_Record):
    """The training data (:class:`~bemlearn.pipeline.results.DataSummary`): ``data``."""

    file: str | None = None
    collected: bool | None = None
    trials: int | None = None
    failed: int | None = None
    samples: int | None = None
    rate_hz: float | None = None
    input_units: str | None = None


@dataclass(kw_only=True)
class DerivativeChoiceInfo(_Record):
    """The Gaussian's σ chosen from the data (:class:`~bemlearn.data.derivative_choice.SigmaChoice`)."""

    sigma_s: float | None = None
    note: str | None = None
    qdd_noise_fraction: dict[str, float] | None = None


@dataclass(kw_only=True)
class DatasetInfo(_Record):
    """How the GP datasets were built (``dataset``: :func:`~bemlearn.data.build_datasets`'s report)."""

    derivative_choice: DerivativeChoiceInfo | None = field(default=None, metadata=_one(DerivativeChoiceInfo))
    estimator: str | None = None


@dataclass(kw_only=True)
class PriorMeanInfo(_Record):
    """The GP's prior mean (``fit.prior_mean``: :func:`~bemlearn.fitting.linear_mean.choose_prior_mean`'s record, or
    the configured one)."""

    chosen: str | None = None
    explained: float | None = None
    nlml_linear: float | None = None
    nlml_zero: float | None = None
    penalty: float | None = None
    estimate: str | None = None


@dataclass(kw_only=True)
class FitInfo(_Record):
    """The GP fit (``fit``)."""

    stop_reason: str | None = None
    steps: int | None = None
    seconds: float | None = None
    prior_mean: PriorMeanInfo | None = field(default=None, metadata=_one(PriorMeanInfo))


@dataclass(kw_only=True)
class RobotInfo(_Record):
    """The robot of the run (``robot``: :meth:`~bemlearn.robots.registry.RobotRef.to_dict`)."""

    name: str | None = None
    mjcf: str | None = None
    sha256: str | None = None
    registry: str | None = None


# ---------------------------------------------------------------- learned vs model BEM


@dataclass(kw_only=True)
class DesignRegionInfo(_Record):
    """Learned vs model BEM over the design region (``bem_design_region``:
    :meth:`~bemlearn.pipeline.design_evaluation.DesignRegionResult.as_dict`)."""

    rmse: float | None = None
    max_abs: float | None = None
    gain: float | None = None
    n_points: int | None = None
    bound: float | None = None
    box: dict[str, dict[str, float]] | None = None
    coverage_2sigma_band: float | None = None
    worst: dict[str, Any] | None = None
    max_sampled: float | None = None
    refine_evaluations: int | None = None


@dataclass(kw_only=True)
class BoundViolationInfo(_Record):
    """How often the eq. (13)/(15) bound fails (``bem_heldout.bound_violation``)."""

    kappa: float | None = None
    observed: float | None = None
    nominal: float | None = None


@dataclass(kw_only=True)
class DesignRegionErrorsInfo(_Record):
    """The held-out errors inside the design region (``bem_heldout.design_region``)."""

    bound: float | None = None
    n_points: int | None = None
    rmse: float | None = None
    max_abs: float | None = None


@dataclass(kw_only=True)
class HeldoutBEM(_Record):
    """Learned vs model BEM along the held-out references (``bem_heldout``)."""

    rmse: float | None = None
    max_abs: float | None = None
    no_model_root: int | None = None
    coverage_2sigma_latent: float | None = None
    coverage_2sigma_predictive: float | None = None
    coverage_2sigma_band: float | None = None
    median_band_std_over_rmse: float | None = None
    bound_violation: BoundViolationInfo | None = field(default=None, metadata=_one(BoundViolationInfo))
    design_region: DesignRegionErrorsInfo | None = field(default=None, metadata=_one(DesignRegionErrorsInfo))


# ---------------------------------------------------------------- from the data alone


@dataclass(kw_only=True)
class HeldoutTrial(_Record):
    """One held-out trial (``data_heldout.per_trial.<id>``)."""

    rmse: float | None = None
    coverage: float | None = None
    n_points: int | None = None
    failed: bool | None = None
    beyond_training: float | None = None


@dataclass(kw_only=True)
class DataHeldout(_Record):
    """q_u of the held-out trials from f(x) (``data_heldout``: :func:`~bemlearn.pipeline.data_evaluation.heldout_prediction`)."""

    rmse: float | None = None
    max_abs: float | None = None
    coverage: float | None = None
    n_points: int | None = None
    per_trial: dict[str, HeldoutTrial] | None = field(default=None, metadata=_by_name(HeldoutTrial))


@dataclass(kw_only=True)
class ResolutionInput(_Record):
    """One actuated input of :class:`Resolution`."""

    input: str | None = None
    slope: float | None = None
    amplitude: float | None = None
    range: list[float] | None = None
    unit: str | None = None
    share: float | None = None
    factor: float | None = None


@dataclass(kw_only=True)
class Resolution(_Record):
    """Do the data resolve the BEM (``resolution``: :func:`~bemlearn.pipeline.data_evaluation.bem_resolution`)?"""

    spread: float | None = None
    band_std: float | None = None
    ratio: float | None = None
    unit: str | None = None
    inputs: tuple[ResolutionInput, ...] | None = field(default=None, metadata=_many(ResolutionInput))


@dataclass(kw_only=True)
class SupportPair(_Record):
    """An unactuated input and the actuated input it moves with most."""

    input: str | None = None
    with_: str | None = field(default=None, metadata={"key": "with"})
    corr: float | None = None
    ratio: float | None = None


@dataclass(kw_only=True)
class SupportInput(_Record):
    """An actuated input's range in the data and among the supported BEM queries."""

    input: str | None = None
    unit: str | None = None
    data: list[float] | None = None
    reach: float | None = None


@dataclass(kw_only=True)
class Support(_Record):
    """Joint support of the BEM queries (``support``: :func:`~bemlearn.pipeline.data_evaluation.design_support`)."""

    share: float | None = None
    limit: float | None = None
    qdd_u: str | None = None
    slope: float | None = None
    t: float | None = None
    lambda2: float | None = None
    pairs: tuple[SupportPair, ...] | None = field(default=None, metadata=_many(SupportPair))
    inputs: tuple[SupportInput, ...] | None = field(default=None, metadata=_many(SupportInput))


@dataclass(kw_only=True)
class SliceSummary(_Record):
    """The BEM slices' predictive σ where covered and extrapolated."""

    n_slices: int | None = None
    std_pred_mean_covered: float | None = None
    std_pred_mean_extrapolated: float | None = None


@dataclass(kw_only=True)
class BemSlices(_Record):
    """The learned BEM on slices through the data (``bem_slices``)."""

    summary: SliceSummary | None = field(default=None, metadata=_one(SliceSummary))


@dataclass(kw_only=True)
class EstimatorTerm(_Record):
    """The neighbouring derivative estimators of the band (eq. E2)."""

    estimators: list[str] | None = None
    median_shift: list[float] | None = None


@dataclass(kw_only=True)
class Uncertainty(_Record):
    """The calibrated band (``uncertainty``: :func:`~bemlearn.pipeline.uncertainty.calibrate_band`)."""

    std_scale: float | None = None
    quantization_step: dict[str, float] | None = None
    estimator_term: EstimatorTerm | None = field(default=None, metadata=_one(EstimatorTerm))


@dataclass(kw_only=True)
class Equilibrium(_Record):
    """The equilibrium the run held (``equilibrium``: :func:`~bemlearn.pipeline.feasibility.equilibrium_stiffness`)."""

    joint: str | None = None
    qu: float | None = None
    unit: str | None = None
    gravity_stiffness: float | None = None
    stable_without_control: bool | None = None


@dataclass(kw_only=True)
class UnactuatedTorque(_Record):
    """A torque logged on q_u (``unactuated_torque``: :mod:`bemlearn.pipeline.logged_torque`)."""

    joint: str | None = None
    unit: str | None = None
    rms: float | None = None
    mean: float | None = None
    shift_rms: float | None = None
    target: float | None = None
    stiffness: float | None = None
    stiffness_unit: str | None = None
    gravity_scale: float | None = None


@dataclass(kw_only=True)
class FailedStage(_Record):
    """Where a run stopped (``failed``: :func:`~bemlearn.pipeline.failure.record_failure`)."""

    stage: str | None = None
    error_type: str | None = None
    error: str | None = None
    kept: list[str] | None = None


# ---------------------------------------------------------------- the closed loop


@dataclass(kw_only=True)
class Lemma1Info(_Record):
    """Lemma 1 along the loop (:class:`~bemlearn.pipeline.results.Lemma1Check`)."""

    r_learned_vs_model_delta_gamma: float | None = None
    r_learned_vs_hdot: float | None = None
    model_gap: float | None = None
    hdot_coefficient: float | None = None
    damping_coefficient: float | None = None
    r_model_damping: float | None = None
    damping_qu: float | None = None
    delta_gamma_qu: float | None = None


@dataclass(kw_only=True)
class LoopMetrics(_Record):
    """One closed loop: ``closed_loop.<source>`` of a run (:meth:`~bemlearn.pipeline.results.LoopResult.summary`)
    or ``<source>`` of ``simulate/metrics.json`` (:meth:`~bemlearn.pipeline.results.LoopResult.as_dict`)."""

    fell: bool | None = None
    diverged: bool | None = None
    duration_s: float | None = None
    tracking_rmse: float | None = None
    tracking_max: float | None = None
    qu_max: float | None = None
    qu_dev_max: float | None = None
    u_max: float | None = None
    real_time_factor: float | None = None
    bem_rejected: int | None = None
    bem_vs_model_rmse: float | None = None
    bem_vs_model_max: float | None = None
    bem_inside_2sigma: float | None = None
    lemma1: Lemma1Info | None = field(default=None, metadata=_one(Lemma1Info))


# ---------------------------------------------------------------- the whole file


def _load_verdict(doc: Mapping[str, Any]) -> Verdict:
    return Verdict.from_dict(dict(doc))


def _verdict() -> dict[str, Any]:
    return {"load": _load_verdict, "dump": lambda v: v.to_dict(), "type": Mapping}


def _checks() -> dict[str, Any]:
    return _many(ModelCheck)


@dataclass(kw_only=True)
class RunMetrics(_Record):
    """A run's ``metrics.json`` (module docstring), one field per entry, ``None`` where the run has none.

    Training's entries: the robot, the GP fit, the datasets' report (``dataset``), the units, q_u's joint
    (``unactuated``) and unit (``output_unit``), the validation figures, the band's calibration
    (``uncertainty``), the data-only checks (``data_heldout``, ``resolution``, ``support``, ``bem_slices``)
    and, with a model, learned vs model BEM (``bem_heldout``, ``bem_design_region``) and a torque logged
    on q_u.  The run adds one :class:`LoopMetrics` per BEM source (``closed_loop``), the data's summary
    (``data``), the model checks (``feasibility``), the equilibrium held, where it failed (``failed``) and
    its :class:`~bemlearn.pipeline.verdict.Verdict`.
    """

    robot: RobotInfo | None = field(default=None, metadata=_one(RobotInfo))
    fit: FitInfo | None = field(default=None, metadata=_one(FitInfo))
    units: dict[str, str] | None = None
    unactuated: str | None = None
    actuated: list[str] | None = None
    output_unit: str | None = None
    n_train: int | None = None
    dataset: DatasetInfo | None = field(default=None, metadata=_one(DatasetInfo))
    interrupted: bool | None = None
    val_rmse: float | None = None
    val_mean_log_likelihood: float | None = None
    uncertainty: Uncertainty | None = field(default=None, metadata=_one(Uncertainty))
    data_heldout: DataHeldout | None = field(default=None, metadata=_one(DataHeldout))
    resolution: Resolution | None = field(default=None, metadata=_one(Resolution))
    support: Support | None = field(default=None, metadata=_one(Support))
    bem_slices: BemSlices | None = field(default=None, metadata=_one(BemSlices))
    bem_heldout: HeldoutBEM | None = field(default=None, metadata=_one(HeldoutBEM))
    bem_design_region: DesignRegionInfo | None = field(default=None, metadata=_one(DesignRegionInfo))
    unactuated_torque: UnactuatedTorque | None = field(default=None, metadata=_one(UnactuatedTorque))
    closed_loop: dict[str, LoopMetrics] | None = field(default=None, metadata=_by_name(LoopMetrics))
    data: DataInfo | None = field(default=None, metadata=_one(DataInfo))
    feasibility: tuple[ModelCheck, ...] | None = field(default=None, metadata=_checks())
    equilibrium: Equilibrium | None = field(default=None, metadata=_one(Equilibrium))
    failed: FailedStage | None = field(default=None, metadata=_one(FailedStage))
    verdict: Verdict | None = field(default=None, metadata=_verdict())

    def unit(self) -> str:
        """q_u's unit (``rad`` where the run does not say)."""
        return self.output_unit or "rad"


def written_verdict(doc: Mapping[str, Any]) -> tuple[str | None, list[str]]:
    """``(status, reasons)`` of the verdict a metrics file holds (a run's, or an application's own that
    writes ``verdict: {status, reasons}``); ``(None, [])`` where it holds none."""
    v = doc.get("verdict")
    if not isinstance(v, Mapping):
        return None, []
    reasons = v.get("reasons") or []
    return (str(v["status"]) if v.get("status") is not None else None), [str(r) for r in reasons]
