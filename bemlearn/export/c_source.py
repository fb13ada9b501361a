"""Generate ``<prefix>_predictor.h`` / ``<prefix>_predictor.c``: the BEM predictor in C99.

The C functions evaluate the folded posterior of the TorchScript module (eq. 12, 14; see
:mod:`bemlearn.export.c_posterior`) with every constant a ``static const`` array:

    <prefix>_mean(x)            μ(x_0^e), x = [q̈_a, q̇_a, q_a] (3m values)  — the control-loop path
    <prefix>_forward(x, &μ, &σ) μ and the calibrated band σ_band (eq. B1), with input checks and an error code
    <prefix>_forward_latent     as ``forward`` with the latent std σ (eq. 12)
    <prefix>_full_mean(x)       mean of the full map f(x), x of 3m + 2 values (eq. 11)
    <prefix>_predict_full(...)  as ``forward`` for f(x); ``<prefix>_predict_full_latent`` its latent std

The std functions mirror the TorchScript ``forward``, ``forward_latent``, ``predict_full`` and
``predict_full_latent``; the band's gradient term reads the module's ``G`` (columns [0, n)) and
``gamma``, its estimator term the K estimator columns of ``G`` (``<prefix>_E``, one copy for
the BEM and the full map, K multiply-adds per support point).

float64 uses the folded exponent of the TorchScript module (n multiply-adds and one ``exp``
per support point, the exp a vectorizable block of :mod:`bemlearn.export.c_exp`); float32 uses the distance form on centered inputs, and is refused, with
the measured error, for posteriors it cannot evaluate accurately
(:mod:`bemlearn.export.c_float32`; docs/c-export.md).  The std sums Σ v_i² with compensated
(Kahan) summation: σ² = var0 − Σ v_i² cancels by var0/σ² near the data.
"""

from __future__ import annotations

import dataclasses
import json
import re
from typing import Literal

import numpy as np
import torch

from bemlearn import __version__
from bemlearn.errors import ArgumentError
from bemlearn.export.bem_predictor import BEMPredictor
from bemlearn.export.c_exp import EXP_BLOCK_F64, EXP_BLOCK_LIBM
from bemlearn.export.c_float32 import Float32Errors, float32_errors, sample_inputs
from bemlearn.export.c_posterior import RANGE_LENGTHSCALES, CPosterior, c_posterior, support_box
from bemlearn.export.c_std_templates import (
    BAND_GRADIENT,
    DENSE_STD,
    ESTIMATOR_TERM,
    FACTORED_STD,
    KERNELS,
    NO_BAND_GRADIENT,
    NO_ESTIMATOR_TERM,
    TRIANGULAR_STD,
)
from bemlearn.export.c_templates import DISTANCE_EXPONENTS, FOLDED_EXPONENTS, HEADER, PLANE, PLANE_VARIANCE, POSTERIOR, SOURCE
from bemlearn.export.folded_posterior import SENTINEL_BOUND, FoldedPosterior
from bemlearn.export.metadata import PredictorMetadata
from bemlearn.export.variance_factor import VarianceFactor
from bemlearn.models.predictor_state import PredictorState

__all__ = ["c_sources", "check_prefix", "machine_independent", "CDtype", "ERROR_CODES", "BLOCK", "F32_MEAN_TOL", "F32_STD_RTOL"]

CDtype = Literal["float64", "float32"]

#: The return codes of ``<prefix>_forward`` / ``<prefix>_predict_full`` (also in the header).
ERROR_CODES = {"OK": 0, "ERR_NONFINITE": 1, "ERR_OUT_OF_RANGE": 2, "ERR_NULL": 3}
#: Support points per block of exponents (the vectorizable inner loop); must match the template.
BLOCK = 32

#: Default float32 tolerances: mean error (rad) and std relative error.
F32_MEAN_TOL = 1e-4
F32_STD_RTOL = 1e-2

_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_PER_LINE = 4


def check_prefix(prefix: str) -> str:
    """``prefix`` if it is a C identifier not reserved to the implementation, else ValueError."""
    if not isinstance(prefix, str) or not _IDENT.match(prefix):
        raise ArgumentError(f"prefix: expected a C identifier ([A-Za-z_][A-Za-z0-9_]*), got {prefix!r}")
    if prefix.startswith("__") or re.match(r"^_[A-Z]", prefix):
        raise ArgumentError(f"prefix: {prefix!r} is reserved in C (leading __ or _ and a capital)")
    return prefix


def _literal(v: float, dtype: CDtype) -> str:
    if dtype == "float64":
        return repr(float(v))
    return np.format_float_scientific(np.float32(v), unique=True, trim="0") + "f"


def _array(name: str, values: np.ndarray, dtype: CDtype, real: str) -> str:
    flat = np.asarray(values, dtype=np.float64).reshape(-1)
    items = [_literal(v, dtype) for v in flat]
    lines = [", ".join(items[i : i + _PER_LINE]) for i in range(0, len(items), _PER_LINE)]
    return f"static const {real} {name}[{len(items)}] = {{\n    " + ",\n    ".join(lines) + "\n};\n"


def _c_chars(text: str, per_line: int = 24) -> str:
    """``text`` (ASCII) as the NUL-terminated initializer of a ``char`` array: its character codes,
    ``per_line`` a line (no string literal, whose length C99 only guarantees up to 4095 characters)."""
    codes = [str(b) for b in text.encode("ascii")] + ["0"]
    return ",\n".join("    " + ", ".join(codes[i : i + per_line]) for i in range(0, len(codes), per_line))


_ABS_PATH = re.compile(r"(?<![\w.~:/-])(?:/|[A-Za-z]:[\\/]|~/)(?:[^\s\"'/\\]+[\\/])+([^\s\"'/\\]+)")


def machine_independent(doc):
    """``doc`` (JSON-like) with every absolute file path (``/home/me/data.npz``, ``C:\\x\\y.xml``,
    ``~/r.xml``), alone or inside a text, reduced to its file name: an exported header carries nothing
    of the machine that exported it."""
    if isinstance(doc, dict):
        return {k: machine_independent(v) for k, v in doc.items()}
    if isinstance(doc, list):
        return [machine_independent(v) for v in doc]
    if isinstance(doc, str):
        if re.fullmatch(r"(?:/|[A-Za-z]:[\\/]|~/)[^\n]*", doc):     # the whole value is a path
            return re.split(r"[\\/]", doc.rstrip("/\\"))[-1]
        return _ABS_PATH.sub(lambda m: m.group(1), doc)
    return doc


def _posterior_constants(p: str, name: str, post: CPosterior, dtype: CDtype, real: str, share_W: str | None,
                         share_P: str | None, share_pk: str | None = None) -> str:
    parts = [
        f"static const int {p}_{name}_centered = {int(post.centered)};\n",
        _array(f"{p}_{name}_a", post.a, dtype, real),
        _array(f"{p}_{name}_nb", post.nb, dtype, real),
        _array(f"{p}_{name}_W2", post.W2, dtype, real),
        _array(f"{p}_{name}_c", post.c, dtype, real),
    ]
    if share_W is None:
        parts.append(_array(f"{p}_{name}_W", post.W, dtype, real))
    else:   # the first n rows of the full map's weights
        parts.append(f"static const {real} *const {p}_{name}_W = {share_W};\n")
    if post.lin is not None:   # the linear prior mean (eq. L1)
        parts.append(_array(f"{p}_{name}_lin", post.lin, dtype, real))
        parts.append(f"static const {real} {p}_{name}_l0 = {_literal(post.l0, dtype)};\n")
    if post.pv is not None:   # the plane coefficients' variance (eq. L3)
        assert post.pv0 is not None and post.pk is not None   # given with pv (c_posterior)
        parts.append(_array(f"{p}_{name}_pv", post.pv, dtype, real))
        parts.append(_array(f"{p}_{name}_pv0", post.pv0, dtype, real))
        if share_pk is None:
            parts.append(_array(f"{p}_{name}_pk", post.pk, dtype, real))
        else:
            parts.append(f"static const {real} *const {p}_{name}_pk = {share_pk};\n")
    if post.banded:   # the band's gradient term (unused, hence not written, without input noise)
        parts.append(_array(f"{p}_{name}_gamma", post.gamma, dtype, real))
        if post.sb is not None:
            parts.append(_array(f"{p}_{name}_sb", post.sb, dtype, real))
        if share_P is None:
            parts.append(_array(f"{p}_{name}_P", post.P, dtype, real))
        else:
            parts.append(f"static const {real} *const {p}_{name}_P = {share_P};\n")
    return "".join(parts)


def _posteriors(predictor: BEMPredictor, state: PredictorState, dtype: CDtype) -> tuple[CPosterior, CPosterior]:
    if dtype == "float64":
        return c_posterior(predictor.bem), c_posterior(predictor.full)
    # float32: centered distance form; w and the variance factor shared with the predictor
    # (with ``share`` the factor argument only sets the signed / triangular flags)
    ref = predictor.full
    empty = torch.zeros(0, 0, dtype=torch.float64)
    signs = ref.signs if ref.signed else None
    if ref.triangular:
        factor = VarianceFactor(L=empty, F=empty, signs=signs) if ref.factored else VarianceFactor(L=empty)
    else:
        factor = VarianceFactor(F=empty, signs=signs)
    full = FoldedPosterior(state, factor, n_inputs=state.dim, share=predictor.full, form="centered")
    bem = FoldedPosterior(state, factor, n_inputs=predictor.n_bem, share=predictor.full, form="centered")
    return c_posterior(bem, form="distance"), c_posterior(full, form="distance")


def _check_float32(predictor: BEMPredictor, state: PredictorState, bem: CPosterior, full: CPosterior, lo: np.ndarray,
                   hi: np.ndarray, mean_tol: float, std_rtol: float) -> Float32Errors:
    """The larger float32 errors of the BEM (``forward``) and the full map (``predict_full``); ValueError above tolerance."""
    errs = [float32_errors(post, ref, sample_inputs(state.Z, state.x_mean, state.x_std, post.n_inputs, lo, hi))
            for post, ref in ((bem, predictor.bem), (full, predictor.full))]
    err = Float32Errors(**{f.name: max(getattr(e, f.name) for e in errs) for f in dataclasses.fields(Float32Errors)})
    if err.mean_abs > mean_tol or max(err.std_rel, err.latent_std_rel) > std_rtol:
        raise ArgumentError(
            f"dtype float32: this {state.kind} posterior cannot be evaluated accurately in float32: on {err.n} in-range "
            f"inputs each of the BEM and the full map the float32 mean is off by up to {err.mean_abs:.2g} rad (tolerance {mean_tol:g}), the std (calibrated "
            f"band) by {err.std_rel:.2g} and the latent std by {err.latent_std_rel:.2g} relative (tolerance "
            f"{std_rtol:g}).  Why: the mean and the band's gradient and estimator terms are sums of terms w_j k_j up to "
            f"{err.weight_sum:.3g} rad in total that cancel, each k_j known to ~1e-6 relative in float32, and the "
            "latent std is sqrt(var0 - sum v_i^2), which cancels near the data.  Use dtype float64 (software double "
            "on an FPU without double precision)."
        )
    return err


def c_sources(
    state: PredictorState,
    metadata: PredictorMetadata,
    *,
    prefix: str = "bem",
    dtype: CDtype = "float64",
    f32_mean_tol: float = F32_MEAN_TOL,
    f32_std_rtol: float = F32_STD_RTOL,
) -> dict[str, str]:
    """The header and source text, ``{"<prefix>_predictor.h": ..., "<prefix>_predictor.c": ...}``.

    Args:
        state: the frozen float64 posterior (exact, sgpr or svgp).
        metadata: its validated metadata (``m`` fixes the input widths).
        prefix: C identifier prefixed to every public name (``bem_mean``, ``BEM_OK``, ...).
        dtype: ``"float64"`` (``double``) or ``"float32"`` (``float``, for FPUs without double).
        f32_mean_tol: float32 only: refuse when the emulated float32 predictor
            (:func:`~bemlearn.export.c_float32.float32_errors`) differs from float64 by more
            than this in the mean (rad) on in-range inputs.
        f32_std_rtol: float32 only: the same for the std (relative).

    Raises:
        ArgumentError: (a ValueError) a bad prefix or dtype, or float32 too inaccurate for this posterior
            (the message gives the measured errors and why).
    """
    p = check_prefix(prefix)
    if dtype not in ("float64", "float32"):
        raise ArgumentError(f"dtype: expected 'float64' or 'float32', got {dtype!r}")
    P = p.upper()
    real, exp, sqrt = ("double", "exp", "sqrt") if dtype == "float64" else ("float", "expf", "sqrtf")
    predictor = BEMPredictor(state, metadata)
    bem, full = _posteriors(predictor, state, dtype)
    n_bem, n_full, M = bem.n_inputs, full.n_inputs, bem.n_support
    if not (np.array_equal(bem.w, full.w) and bem.y0 == full.y0 and np.array_equal(bem.factor, full.factor)
            and bem.scale2 == full.scale2 and np.array_equal(bem.E, full.E)
            and (bem.inner is None) == (full.inner is None) and (bem.inner is None or np.array_equal(bem.inner, full.inner))):  # type: ignore[arg-type]  # both None or both arrays
        raise AssertionError("c_sources: the BEM and full posteriors must share w, y0, the variance factor, c and E")
    K = bem.n_estimators
    lo, hi = support_box(state.Z, state.x_mean, state.x_std, state.lengthscale)
    doc = json.loads(predictor.metadata_json)
    f32 = _check_float32(predictor, state, bem, full, lo, hi, f32_mean_tol, f32_std_rtol) if dtype == "float32" else None
    doc["c_export"] = {
        "prefix": p, "dtype": dtype, "form": bem.form, "n_estimators": K,
        "error_codes": {f"{P}_{k}": v for k, v in ERROR_CODES.items()},
        "input_range": {"rule": f"support points' box +- {RANGE_LENGTHSCALES:g} lengthscales",
                        "lo": lo[:n_bem].tolist(), "hi": hi[:n_bem].tolist(),
                        "full_lo": lo.tolist(), "full_hi": hi.tolist()},
    }
    if f32 is not None:
        doc["c_export"]["float32_error"] = {
            "mean_abs": f32.mean_abs, "std_rel": f32.std_rel, "std_abs": f32.std_abs,
            "latent_std_rel": f32.latent_std_rel, "latent_std_abs": f32.latent_std_abs, "n_inputs": f32.n,
            "how": "float32 algorithm emulated in NumPy vs the float64 predictor on the support points and random in-range inputs, "
                   "BEM and full map, the larger error of the two",
        }
    share = f"{p}_full_W" if bem.form == full.form and np.array_equal(bem.W, full.W[:n_bem]) else None
    share_P = f"{p}_full_P" if bem.banded and full.banded and np.array_equal(bem.P, full.P[:n_bem]) else None
    share_pk = (f"{p}_full_pk" if bem.pk is not None and full.pk is not None and np.array_equal(bem.pk, full.pk)
                else None)
    sub = {"p": p, "P": P, "real": real, "exp": exp, "sqrt": sqrt}
    exponents = DISTANCE_EXPONENTS if bem.form == "distance" else FOLDED_EXPONENTS
    signed_term = "s * s" if bem.signs is None else f"{p}_signs[i] * s * s"
    if bem.inner is not None:     # factored sparse: triangular solve, then the inner factor R
        std = FACTORED_STD.substitute(sub, signed_term=signed_term)
    elif bem.triangular:
        std = TRIANGULAR_STD.substitute(sub)
    else:
        std = DENSE_STD.substitute(sub, signed_term=signed_term)
    constants = "".join([
        _posterior_constants(p, "full", full, dtype, real, None, None),
        _posterior_constants(p, "bem", bem, dtype, real, share, share_P, share_pk),
        _array(f"{p}_w", bem.w, dtype, real),
        f"static const {real} {p}_y0 = {_literal(bem.y0, dtype)};\n",
        f"static const {real} {p}_var0 = {_literal(bem.var0, dtype)};\n",
        f"static const {real} {p}_scale2 = {_literal(bem.scale2, dtype)};   /* std_scale^2 of the band */\n",
        _array(f"{p}_factor", bem.factor, dtype, real),
        "" if bem.inner is None else _array(f"{p}_inner", bem.inner, dtype, real),
        "" if bem.signs is None else _array(f"{p}_signs", bem.signs, dtype, real),
        _array(f"{p}_E", bem.E, dtype, real) if K else "",   # the band's estimator term (K x M)
    ])
    exp_block = (EXP_BLOCK_F64 if dtype == "float64" else EXP_BLOCK_LIBM).substitute(sub)
    source = SOURCE.substitute(
        sub, version=__version__, constants=constants, exp_block=exp_block,
        exponents="\n".join(exponents.substitute(sub, name=nm, n=n) for nm, n in (("bem", n_bem), ("full", n_full))),
        std=KERNELS.substitute(sub) + "\n" + std + "\n" + (ESTIMATOR_TERM if K else NO_ESTIMATOR_TERM).substitute(sub) + "\n"
            + "\n".join((BAND_GRADIENT if post.banded else NO_BAND_GRADIENT).substitute(
                             sub, name=nm, n=post.n_inputs, sb_term="" if post.sb is None else f" + {p}_{nm}_sb[i]")
                         for nm, post in (("bem", bem), ("full", full))),
        posteriors="\n".join(POSTERIOR.substitute(sub, name=nm, n=post.n_inputs, lo=f"{p}_{pre}input_lo", hi=f"{p}_{pre}input_hi",
                                                   beyond=f"!(s >= {-0.5 * SENTINEL_BOUND!r}) ? 2 : 0" if dtype == "float64" else "0",
                                                   plane="" if post.lin is None else f" + {p}_{nm}_plane(v)",
                                                   plane_fn=("" if post.lin is None else PLANE.substitute(sub, name=nm, n=post.n_inputs))
                                                            + ("" if post.pv is None else PLANE_VARIANCE.substitute(
                                                                sub, name=nm, n=post.n_inputs, n_terms=post.n_plane_terms)),
                                                   pv_pre="" if post.pv is None else f"{real} pv = {p}_{nm}_plane_var(v, k);   /* eq. L3 */\n    ",
                                                   pv_add="" if post.pv is None else " + pv")
                              for nm, post, pre in (("bem", bem, ""), ("full", full, "full_"))),
    )
    units = doc["units"]
    size = 8 if dtype == "float64" else 4
    header = HEADER.substitute(
        sub, robot=doc["robot"], kind=state.kind, version=__version__, m=metadata.m, n_bem=n_bem, n_full=n_full,
        n_support=M, dtype=dtype, range_ls=f"{RANGE_LENGTHSCALES:g}", banded=int(bem.banded), full_banded=int(full.banded),
        n_estimators=K, std_scale=f"{np.sqrt(bem.scale2):.6g}",
        bem_columns=", ".join(doc["inputs"]), full_columns=", ".join(doc["full_inputs"]),
        units="; ".join(f"{k} [{units[k]}]" for k in doc["full_inputs"]) + "; mean, std [rad]",
        stack_bytes=size * (M + 2 * BLOCK + n_full) + 1024,
        bem_lo=", ".join(_literal(v, dtype) for v in lo[:n_bem]), bem_hi=", ".join(_literal(v, dtype) for v in hi[:n_bem]),
        full_lo=", ".join(_literal(v, dtype) for v in lo), full_hi=", ".join(_literal(v, dtype) for v in hi),
        metadata=_c_chars(json.dumps(machine_independent(doc), allow_nan=False, ensure_ascii=True, separators=(",", ":"))),
    )
    return {f"{p}_predictor.h": _ascii(header), f"{p}_predictor.c": _ascii(source)}


def _ascii(text: str) -> str:
    """C sources in ASCII: superscripts as ^2, ^3, anything else non-ASCII as a \\x escape (comments only)."""
    return text.replace("²", "^2").replace("³", "^3").encode("ascii", "backslashreplace").decode("ascii")
