"""AOTInductor artifact ``bem_predictor_aoti.pt2``: the predictor compiled ahead of time to native code.

Each method of :class:`~bemlearn.export.bem_predictor.BEMPredictor` is exported with
``torch.export`` (the programs of :mod:`bemlearn.export.pt2`, dynamic B ≥ 1) and compiled by
AOTInductor (``torch._inductor.aot_compile`` with ``aot_inductor.package``, what
``torch._inductor.aoti_compile_and_package`` runs for one program) into a shared library;
the libraries go into one PT2 package, one named model per method (torch 2.13 packages
several models with ``package_pt2(aoti_files={name: files})``):

    data/aotinductor/model/…          forward(x: (B, 3m)) -> [mean (B,), std (B,)]
    data/aotinductor/bem_mean/…       bem_mean(x: (B, 3m)) -> [mean (B,)]
    data/aotinductor/predict_full/…, full_mean/…, forward_latent/…, predict_full_latent/…
    extra/metadata.json               the metadata() JSON document

Each model's own metadata (``AOTIModelPackageLoader::get_metadata()``) carries
``bemlearn_method`` and the whole document as ``bemlearn_metadata``, so C++ reads it without
unzipping.  Loading: ``torch._inductor.package.load_package(path, name)`` or
``torch._C._aoti.AOTIModelPackageLoader`` in Python, ``torch::inductor::AOTIModelPackageLoader(path,
name)`` in C++; :func:`load_aoti_predictor` returns an :class:`AotiPredictor` with the contract's
methods and input checks.

What the compiled code checks by itself: B ≥ 1 and a finite mean (non-finite inputs, and the
range rule ‖u‖ > 10¹⁵⁰), each a ``std::runtime_error`` with a ``BEMPredictor.<method>: …``
message.  What it does **not** check: rank, width, dtype, device, contiguity — a float32 or
too-narrow tensor is read as if it were right (see docs/predictor-contract.md).

The package holds native code compiled with the build machine's instruction set
(``-march=native``): build it on (a CPU like) the controller's.  Loading it runs that code:
load only packages you built.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import tempfile
import time
import warnings
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import torch

from bemlearn.errors import ArgumentError, CheckpointError, EnvironmentProblem, MissingFileError
from bemlearn.export.bem_predictor import BEMPredictor
from bemlearn.export.checked_predictor import CheckedPredictor
from bemlearn.export.pt2 import PT2_METADATA_FILE, PT2_PROGRAMS, export_programs

__all__ = ["aoti_bytes", "load_aoti_predictor", "AotiPredictor", "AOTI_PROGRAMS", "find_cxx"]

log = logging.getLogger(__name__)

#: Model name in the package → BEMPredictor method it compiles (the names of the ``.pt2``).
AOTI_PROGRAMS = dict(PT2_PROGRAMS)


def find_cxx() -> str | None:
    """The C++ compiler AOTInductor will call (``CXX``, else ``c++``/``g++``/``clang++`` on PATH), or None."""
    import shutil

    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def _drop_proxy_fallback(record: logging.LogRecord) -> bool:
    return "is missing a c-shim implementation, using proxy executor as fallback" not in record.getMessage()


@contextlib.contextmanager
def _quiet_compile() -> Iterator[None]:
    """Silence the messages torch 2.13 prints while compiling the programs, all about its own code:
    pytree's ``LeafSpec`` deprecation inside AOTInductor's pickling, the shared-weight group note,
    and the log line that ``linalg_solve_triangular`` (the exact variance, eq. 12) has no C shim
    and runs through torch's proxy executor (correct, and measured: docs/predictor-speed.md)."""
    inductor_log = logging.getLogger("torch._inductor.ir")
    inductor_log.addFilter(_drop_proxy_fallback)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)` is deprecated", category=FutureWarning)
            warnings.filterwarnings("ignore", message="No complete tensor found in the group")
            yield
    finally:
        inductor_log.removeFilter(_drop_proxy_fallback)


def aoti_bytes(predictor: BEMPredictor, *, programs: tuple[str, ...] = tuple(AOTI_PROGRAMS)) -> bytes:
    """Compile ``predictor``'s methods with AOTInductor and return the PT2 package, in memory.

    Each method takes one ``torch._inductor.aot_compile`` (a C++ compile and link, ≈ 10 s here;
    the first on a machine ≈ 30 s more, building torch's precompiled header).

    Args:
        programs: the package's model names (default: every method of the contract).

    Raises:
        EnvironmentProblem: no C++ compiler, or AOTInductor failed (its error is in the message).
    """
    if find_cxx() is None:
        raise EnvironmentProblem("--format aoti: AOTInductor needs a C++ compiler (c++, g++ or clang++ on PATH, or CXX)")
    unknown = sorted(set(programs) - set(AOTI_PROGRAMS))
    if unknown:
        raise ArgumentError(f"programs: unknown {unknown}; expected names from {sorted(AOTI_PROGRAMS)}")
    exported = export_programs(predictor, names=programs)
    files: dict[str, list] = {}
    with tempfile.TemporaryDirectory(prefix="bemlearn-aoti-") as tmp, _quiet_compile():
        for name in programs:
            t0 = time.perf_counter()
            ep = exported[name]
            options = {
                "aot_inductor.package": True,
                # a fresh folder per program: torch's default (its cache dir, named after a hash of the
                # generated code) can hand back another predictor's files when a model name is set
                "aot_inductor.output_path": str(Path(tmp) / name),
                "aot_inductor.metadata": {"bemlearn_method": AOTI_PROGRAMS[name], "bemlearn_metadata": predictor.metadata_json},
            }
            try:
                with torch.no_grad():
                    out = torch._inductor.aot_compile(ep.module(), ep.example_inputs[0], options=options)
            except (RuntimeError, OSError) as exc:   # CppCompileError is a RuntimeError; a missing tool an OSError
                raise EnvironmentProblem(f"AOTInductor could not compile {name}: {type(exc).__name__}: "
                                         f"{str(exc).strip()[-2000:]}") from exc
            assert isinstance(out, list)   # aot_inductor.package: the generated files
            files[name] = out
            log.info("AOTInductor compiled %s in %.1f s", name, time.perf_counter() - t0)
        buf = io.BytesIO()
        from torch.export.pt2_archive._package import package_pt2

        package_pt2(buf, aoti_files=files, extra_files={PT2_METADATA_FILE: predictor.metadata_json})
    return buf.getvalue()


def _package_contents(data: bytes, where: str) -> tuple[set[str], str]:
    """(model names, metadata JSON) of an AOTInductor package, read as a zip (nothing loaded)."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            names = zf.namelist()
            models = {n.split("/")[3] for n in names if n.count("/") >= 4 and n.split("/")[1:3] == ["data", "aotinductor"]}
            meta = [n for n in names if n.split("/", 1)[-1] == f"extra/{PT2_METADATA_FILE}"]
            text = zf.read(meta[0]).decode() if meta else ""
    except (zipfile.BadZipFile, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{where}: not an AOTInductor package ({exc})") from None
    return models, text


class AotiPredictor(CheckedPredictor):
    """The loaded AOTInductor package: the contract's methods on the compiled models.

    Each call checks ``x`` (rank, width, dtype, device, contiguity: attribute reads only; a
    non-contiguous tensor is copied) and runs the model's ``AOTIModelPackageLoader.run``.

    Args:
        path: the package file (read when constructed; torch extracts it to a temporary folder).
        metadata_json: the metadata document.
        programs: the model names to load (default: all of :data:`AOTI_PROGRAMS`).
    """

    def __init__(self, path: str | os.PathLike[str], metadata_json: str, *, programs: tuple[str, ...] = tuple(AOTI_PROGRAMS)) -> None:
        self.loaders = {name: torch._C._aoti.AOTIModelPackageLoader(str(path), name, False, 1, -1) for name in programs}
        methods: dict[str, Callable[[torch.Tensor], Any]] = {
            AOTI_PROGRAMS[name]: (_mean_method if AOTI_PROGRAMS[name] in ("bem_mean", "full_mean") else _pair_method)(loader.run)
            for name, loader in self.loaders.items()
        }
        super().__init__(metadata_json, methods)


def _mean_method(run: Callable[[list[torch.Tensor]], list[torch.Tensor]]) -> Callable[[torch.Tensor], torch.Tensor]:
    def call(x: torch.Tensor) -> torch.Tensor:
        return run([x])[0]
    return call


def _pair_method(run: Callable[[list[torch.Tensor]], list[torch.Tensor]]) -> Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]:
    def call(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = run([x])
        return out[0], out[1]
    return call


def load_aoti_predictor(path: str | os.PathLike[str] | bytes, *, where: str | os.PathLike[str] | None = None) -> AotiPredictor:
    """Load an AOTInductor package written by ``bemlearn export --format aoti``.

    The package is native code: loading it runs code compiled into it.  This function checks
    only that the file is a package with every model of :data:`AOTI_PROGRAMS` and the metadata
    (a pre-load integrity check can wrap it).

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        CheckpointError: not an AOTInductor package, or not a bemlearn predictor.
    """
    if isinstance(path, bytes):
        data, name = path, str(where or "<AOTInductor package bytes>")
    else:
        name = str(where or path)
        try:
            data = Path(path).read_bytes()
        except FileNotFoundError:
            raise MissingFileError(f"{path}: no such AOTInductor predictor package") from None
    models, meta = _package_contents(data, name)
    missing = [m for m in AOTI_PROGRAMS if m not in models]
    if missing or not meta:
        raise CheckpointError(f"{name}: not a bemlearn AOTInductor predictor (missing {missing or ['extra/' + PT2_METADATA_FILE]})")
    with tempfile.TemporaryDirectory(prefix="bemlearn-aoti-load-") as tmp:
        file = Path(tmp) / "package.pt2"   # torch's loader reads a path; it extracts the libraries itself
        file.write_bytes(data)
        try:
            return AotiPredictor(file, meta)
        except RuntimeError as exc:
            raise CheckpointError(f"{name}: torch cannot load the AOTInductor package: {str(exc).strip()[:500]}") from None
