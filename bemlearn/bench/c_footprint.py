"""Flash and RAM footprint of the C export per model size and kind (``bemlearn bench c-footprint``).

For each model (exact N = 100 … 1000, sgpr/svgp M = 64 … 512; m = 1, d = 5) the C export is
compiled to an object file with ``cc -std=c99 -O2 -ffunction-sections -fdata-sections -c`` and
measured with ``size -A``: code (``.text*``), constants (``.rodata*``), split into those the
mean path reads and the std's constants (the variance factor ``<prefix>_factor``, the factored
sparse kinds' inner factor ``<prefix>_inner``, ``<prefix>_signs`` and, with input noise, the band's ``_P`` and ``_gamma`` (and ``_E``, its estimator term); a firmware that
never calls ``_forward``/``_predict_full`` drops them with ``-Wl,--gc-sections``), and writable
data (``.data``/``.bss``: none).  The stack per call is gcc's ``-fstack-usage`` frame of
``bem_mean`` / ``bem_forward`` (with its evaluator ``bem_bem_eval`` when not inlined) plus the
largest frame of the static helpers they call (libm's ``exp`` not counted).

Sizes are of this host's object code (x86-64); the constants are the same bytes on any
target, the code differs by a few kB.  The posteriors are synthetic (random support points
and weights): footprint depends only on the kind, M, d and the dtype.
"""

from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, cast

import torch

from bemlearn.bench.predict_bench import synthetic_posterior
from bemlearn.errors import EnvironmentProblem
from bemlearn.export.c_build import find_cc
from bemlearn.export.c_source import c_sources
from bemlearn.models.gp_kinds import gp_class
from bemlearn.models.predictor_state import GPKind

__all__ = ["Footprint", "measure_footprints", "format_footprints", "SIZES"]

SIZES: dict[str, tuple[int, ...]] = {"exact": (100, 250, 500, 1000), "sgpr": (64, 128, 256, 512), "svgp": (64, 128, 256, 512)}


@dataclass(frozen=True)
class Footprint:
    """Bytes of one compiled export."""

    kind: str
    M: int
    dtype: str
    code: int
    rodata_mean: int
    rodata_std: int
    data: int
    stack_mean: int
    stack_forward: int

    @property
    def flash_mean(self) -> int:
        return self.code + self.rodata_mean

    @property
    def flash_all(self) -> int:
        return self.code + self.rodata_mean + self.rodata_std


def _sparse_state(kind: GPKind, M: int, seed: int = 0):
    """A synthetic sgpr/svgp posterior: M support points, S = K⁻¹ − K⁻¹ S_u K⁻¹ with S_u = ½ K, held
    factored as trained sparse posteriors are: S = L⁻ᵀ C L⁻¹, L Lᵀ = K, C = ½ I."""
    state, meta = synthetic_posterior(n_train=M, seed=seed, noise=1e-3)
    K = state.gram()
    L = torch.linalg.cholesky(K)
    Ki = torch.cholesky_inverse(L)
    S = Ki - Ki @ (0.5 * K) @ Ki
    state = dataclasses.replace(state, kind=kind, S=0.5 * (S + S.T), S_chol=L,
                                S_inner=0.5 * torch.eye(M, dtype=torch.float64))
    meta = dataclasses.replace(meta, n_inducing=M)
    return state, meta


def _sections(obj: Path) -> dict[str, int]:
    out = subprocess.run(["size", "-A", str(obj)], check=True, capture_output=True, text=True).stdout
    return {m.group(1): int(m.group(2)) for m in re.finditer(r"^(\.\S+)\s+(\d+)", out, re.M)}


def _stack_frames(su: Path) -> dict[str, int]:
    """Frame bytes per function from gcc's ``-fstack-usage`` file."""
    out = {}
    for line in su.read_text().splitlines():
        loc, nbytes, _ = line.split("\t")
        out[loc.rsplit(":", 1)[-1]] = int(nbytes)
    return out


def measure_footprints(sizes: dict[str, tuple[int, ...]] = SIZES, dtypes: tuple[Literal["float64", "float32"], ...] = ("float64", "float32")) -> list[Footprint]:
    """Compile and measure every (kind, M, dtype); needs ``cc`` and binutils ``size``."""
    cc = find_cc()
    if cc is None or shutil.which("size") is None:
        raise EnvironmentProblem("bench c-footprint: needs a C compiler and binutils `size` on PATH")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind, Ms in sizes.items():
            for M in Ms:
                state, meta = _sparse_state(cast(GPKind, kind), M) if gp_class(kind).sparse else synthetic_posterior(n_train=M, seed=0)
                for dtype in dtypes:
                    files = c_sources(state, meta, dtype=dtype, f32_mean_tol=float("inf"), f32_std_rtol=float("inf"))
                    for name, text in files.items():
                        Path(tmp, name).write_text(text)
                    obj = Path(tmp, "bem.o")
                    subprocess.run([cc, "-std=c99", "-O2", "-ffunction-sections", "-fdata-sections", "-fstack-usage", "-c",
                                    str(Path(tmp, "bem_predictor.c")), "-o", str(obj)], check=True, capture_output=True)
                    sec = _sections(obj)
                    code = sum(v for k, v in sec.items() if k.startswith(".text"))
                    std = sum(v for k, v in sec.items() if re.match(r"\.rodata\.bem_(factor|inner|signs|bem_P|full_P|bem_gamma|full_gamma|E)$", k))
                    rodata = sum(v for k, v in sec.items() if k.startswith(".rodata"))
                    data = sum(v for k, v in sec.items() if k.startswith((".data", ".bss")))
                    frames = _stack_frames(obj.with_suffix(".su"))
                    helpers = max(v for k, v in frames.items()
                                  if k == "bem_latent_var" or k.endswith(("_exponents", "_prepare", "_sum", "_sum_k", "_gradient2", "_estimator2")))
                    forward = frames["bem_forward"] + frames.get("bem_bem_eval", 0)   # the evaluator, when not inlined
                    rows.append(Footprint(kind, M, dtype, code, rodata - std, std, data,
                                          stack_mean=frames["bem_mean"] + helpers, stack_forward=forward + helpers))
    return rows


def _kb(n: int) -> str:
    return f"{n / 1024:.1f}"


def format_footprints(rows: list[Footprint]) -> str:
    """Markdown table; flash in KiB (code + constants), fits judged on the whole export (mean + std)."""
    lines = ["| kind | M | dtype | code KiB | mean constants KiB | std factor KiB | flash, mean only KiB | flash, all KiB "
             "| .data/.bss B | stack bem_mean B | stack forward B | fits (all / mean only) |",
             "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in rows:
        lines.append(f"| {r.kind} | {r.M} | {r.dtype} | {_kb(r.code)} | {_kb(r.rodata_mean)} | {_kb(r.rodata_std)} | "
                     f"{_kb(r.flash_mean)} | {_kb(r.flash_all)} | {r.data} | {r.stack_mean} | {r.stack_forward} | "
                     f"{_fits(r.flash_all, r)} / {_fits(r.flash_mean, r)} |")
    return "\n".join(lines)


#: Assumed targets: flash bytes (and RAM for the stack).
TARGETS = (("ESP32", 4 * 1024**2), ("STM32F4", 1024**2), ("Uno", 32 * 1024))


def _fits(flash: int, r: Footprint) -> str:
    # leave half of the flash to the rest of the firmware; the Uno (AVR) has no double and
    # 2 KiB of SRAM, into which avr-gcc copies const data unless it is placed with PROGMEM
    ok = [name for name, cap in TARGETS if flash <= cap // 2 and not (name == "Uno" and (r.dtype == "float64" or r.rodata_mean > 1024))]
    return ", ".join(ok) if ok else "none"
