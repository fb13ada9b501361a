"""Only bemlearn's own predictor code is loaded: a received archive is compared with what this
version's exporter writes, before torch reads it (docs/safety.md, "Files you receive").

A TorchScript ``.pt`` is a zip of code (``code/**/*.py``, compiled by ``torch.jit.load``; a
class's ``__setstate__`` runs while loading), pickles (``data.pkl``, ``constants.pkl``,
``*.debug_pkl``) and raw tensor payloads.  A ``.pt2`` is a zip of graph JSON naming ATen
operators, symbolic-shape strings (torch parses them with ``sympy.sympify``, an ``eval``) and
guard code (compiled to Python by ``ExportedProgram.module()``).  Any of these can run code, so:

* :func:`torchscript_allowlist` exports reference predictors with this version's exporter —
  one per combination of the structural flags of
  :class:`~bemlearn.export.folded_posterior.FoldedPosterior` (every ``bool`` it declares: raw or
  centred inputs, triangular / factored / signed variance, band or not), which are all the code
  the exporter can write — and keeps each method's code with numbers and free text abstracted
  (:func:`bemlearn.safe_load.normalized_script_code`), the globals its pickles name and its
  member names.  :func:`check_torchscript_archive` refuses an archive with any other member,
  class, method (an added ``__setstate__``), statement, operator call, pickle global or a
  storage larger than its payload.
* :func:`pt2_allowlist` collects the operators of reference ``.pt2`` programs;
  :func:`check_pt2_programs` refuses a program named outside
  :data:`~bemlearn.export.pt2.PT2_PROGRAMS`, a node calling any other operator, custom objects,
  guard code, and symbolic-shape strings naming anything but sympy's ``Symbol``, ``Integer``,
  ``Add``, ``Mul`` and symbols.

The allow-lists are derived by the exporter that is running (about 3 s for TorchScript, 3 s
for ``.pt2`` on 2 busy cores) and kept, as SHA-256 digests, in the user's cache folder under a
key that hashes torch's version and the exporter's sources (:func:`_cache_file`).  What a predictor that passes can still do: return wrong numbers (its tensors
are data), fail, or be slow — the operators of a GP posterior on a float64 batch, nothing else.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import hashlib
import io
import itertools
import json
import logging
import os
import re
import sys
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from bemlearn.errors import CheckpointError
from bemlearn.safe_load import STORAGE_ITEMSIZE, normalized_script_code, scan_pickle

__all__ = ["TorchScriptAllowList", "torchscript_allowlist", "check_torchscript_archive", "pt2_allowlist",
           "check_pt2_programs", "structural_flags", "reference_predictor"]

log = logging.getLogger(__name__)

_MANGLE = re.compile(r"___torch_mangle_\d+")
#: Members a bemlearn TorchScript predictor consists of (paths below the archive's root folder).
_TS_MEMBERS = tuple(re.compile(p) for p in (
    r"version", r"byteorder", r"\.data/version", r"\.data/serialization_id", r"extra/metadata\.json",
    r"data\.pkl", r"constants\.pkl", r"data/\d+", r"constants/\d+",
    r"code/__torch__/bemlearn/export/bem_predictor(/___torch_mangle_\d+)?\.py(\.debug_pkl)?",
))
_REFUSED = "refused: not a predictor written by this version of bemlearn's exporter"
_REEXPORT = "re-export it from its run with `bemlearn export RUN_DIR`"


def structural_flags() -> tuple[str, ...]:
    """The ``bool`` attributes of FoldedPosterior: the only switches of the exported code's structure."""
    from bemlearn.export.folded_posterior import FoldedPosterior

    return tuple(k for k, v in FoldedPosterior.__annotations__.items() if v in (bool, "bool"))


def reference_predictor(*, m: int = 1, n_support: int = 4):
    """A small exact-GP :class:`~bemlearn.export.bem_predictor.BEMPredictor` (deterministic numbers)
    whose code is what the exporter writes for every predictor with the same flags."""
    from bemlearn.export.bem_predictor import BEMPredictor
    from bemlearn.export.metadata import PredictorMetadata
    from bemlearn.models.predictor_state import PredictorState

    d = 3 * m + 2
    f64: dict[str, Any] = dict(dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    Z = torch.randn(n_support, d, generator=g, **f64)
    names = tuple([f"qdd_a{i}" for i in range(m)] + [f"qd_a{i}" for i in range(m)] + [f"q_a{i}" for i in range(m)]
                  + ["qdd_u", "qd_u"])
    state = PredictorState(kind="exact", Z=Z, alpha=torch.linspace(-1, 1, n_support, **f64), S=torch.zeros(n_support, n_support, **f64),
                           lengthscale=torch.ones(d, **f64), outputscale=torch.tensor(1.0, **f64), noise=torch.tensor(0.1, **f64),
                           x_mean=torch.zeros(d, **f64), x_std=torch.ones(d, **f64), y_mean=torch.tensor(0.0, **f64),
                           y_std=torch.tensor(1.0, **f64), input_names=names, n_train=n_support)
    state = dataclasses.replace(state, S=torch.cholesky_inverse(torch.linalg.cholesky(state.gram())))
    actuated = tuple(f"a{i}" for i in range(m))
    meta = PredictorMetadata(robot="reference", joint_names=(*actuated, "u"), actuated_names=actuated, unactuated_name="u", m=m,
                             input_names=names, units={n: "rad" for n in names}, n_train=n_support, n_inducing=None,
                             hyperparameters={}, bemlearn_version="reference", data_sha256="0" * 64)
    return BEMPredictor(state, meta)


def _with_flags(predictor, bem: dict[str, bool], full: dict[str, bool]):
    """A copy of ``predictor`` whose posteriors take the given flags, with buffers of consistent shapes."""
    p = copy.deepcopy(predictor)
    M = int(p.full.w.shape[0]) - 1
    f64: dict[str, Any] = dict(dtype=torch.float64)
    flags = {**bem}
    for name, value in full.items():
        flags[name] = flags.get(name, False) or value
    FT = torch.eye(M + 1, **f64) if flags.get("triangular", True) else torch.ones(M + 1, M, **f64)
    RT = torch.ones(M + 1, M, **f64) if flags.get("factored", False) else torch.zeros(0, 0, **f64)
    signs = torch.ones(M, **f64) if flags.get("signed", False) else torch.zeros(0, **f64)
    for sub, chosen in ((p.bem, bem), (p.full, full)):
        for name, value in chosen.items():
            setattr(sub, name, value)
        sub.FT, sub.RT, sub.signs = FT, RT, signs
        # the linear prior mean's buffers with values no other buffer has (equal constant tensors share one name in
        # the exported code; a fitted plane and its band term never equal another buffer)
        n = int(sub.sb.shape[0])
        sub.plane, sub.sb = torch.linspace(0.11, 0.19, n + 1, **f64), torch.linspace(0.21, 0.29, n, **f64)
        # the plane coefficients' variance maps (eq. L3), one column
        sub.PV = torch.linspace(0.31, 0.39, n + 1, **f64)[:, None].contiguous()
        sub.PK = torch.linspace(0.41, 0.49, M + 1, **f64)[:, None].contiguous()
    return p


def _flag_combinations() -> list[dict[str, bool]]:
    names = structural_flags()
    combos = [dict(zip(names, values)) for values in itertools.product((False, True), repeat=len(names))]
    # the variance paths the exporter writes: a triangular solve (exact), then a dense factor
    # (factored sparse), or a dense factor alone; a factored one is always triangular; the plane's band term
    # exists only with the plane and the band's gradient term
    return [c for c in combos if not (c.get("factored") and not c.get("triangular"))
            and not (c.get("plane_band") and not (c.get("linear") and c.get("banded")))]


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _cache_file(kind: str) -> Path:
    """``$XDG_CACHE_HOME/bemlearn/<kind>-<key>.json``, the key a hash of torch's and Python's versions and
    of the exporter's sources: a cached allow-list is used only by the exporter that derived it."""
    here = Path(__file__).resolve().parent
    key = hashlib.sha256(f"{torch.__version__} {sys.version}".encode())
    for source in sorted(here.glob("*.py")) + [here.parent / "safe_load.py", here.parent / "models" / "predictor_state.py"]:
        key.update(source.name.encode() + source.read_bytes())
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return root / "bemlearn" / f"{kind}-{key.hexdigest()[:32]}.json"


def _cached(kind: str, derive):
    """The JSON document ``derive()`` returns, kept in :func:`_cache_file` (a user-writable cache is
    no weaker than the user's own files; it only saves the seconds of the reference exports)."""
    try:
        path = _cache_file(kind)
        return json.loads(path.read_text())
    except (OSError, ValueError):
        pass
    doc = derive()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(doc))
        os.replace(tmp, path)
    except OSError as exc:  # a read-only home: derive again next time
        log.debug("cannot cache the predictor allow-list in %s: %s", path, exc)
    return doc


@dataclass(frozen=True)
class TorchScriptAllowList:
    """What this exporter writes into a TorchScript predictor (see module docstring), as SHA-256
    digests of the normalized code.

    Attributes:
        skeletons: the normalized module with its methods removed.
        methods: method name → the normalized code it may have.
        pickle_globals: pickle kind (``data.pkl``, ``constants.pkl``, ``debug_pkl``) → the
            globals it may name (mangle suffixes normalized).
    """

    skeletons: frozenset[str]
    methods: dict[str, frozenset[str]]
    pickle_globals: dict[str, frozenset[str]]


def _pickle_kind(rel: str) -> str | None:
    if rel in ("data.pkl", "constants.pkl"):
        return rel
    if rel.endswith(".debug_pkl"):
        return "debug_pkl"
    return None


@functools.cache
def torchscript_allowlist(export: Callable[[Any], bytes]) -> TorchScriptAllowList:
    """Export the reference predictors (every flag combination) with ``export`` (the exporter's
    ``torchscript_bytes``) and collect their code (cached: :func:`_cache_file`)."""
    doc = _cached("torchscript-allowlist", functools.partial(_derive_torchscript_allowlist, export))
    return TorchScriptAllowList(frozenset(doc["skeletons"]), {k: frozenset(v) for k, v in doc["methods"].items()},
                                {k: frozenset(v) for k, v in doc["pickle_globals"].items()})


def _derive_torchscript_allowlist(torchscript_bytes: Callable[[Any], bytes]) -> dict[str, Any]:
    base = reference_predictor()
    combos = _flag_combinations()
    skeletons: set[str] = set()
    methods: dict[str, set[str]] = {}
    globs: dict[str, set[str]] = {}
    for flags in combos:
        data = torchscript_bytes(_with_flags(base, flags, flags))
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            for name in zf.namelist():
                rel = name.split("/", 1)[1]
                if rel.startswith("code/") and rel.endswith(".py"):
                    code = normalized_script_code(zf.read(name).decode(), where="reference predictor")
                    skeletons.add(_digest(code.skeleton))
                    for method, dump in code.methods.items():
                        methods.setdefault(method, set()).add(_digest(dump))
                elif (kind := _pickle_kind(rel)) is not None:
                    scan = scan_pickle(zf.read(name), where="reference predictor")
                    globs.setdefault(kind, set()).update(_MANGLE.sub("___torch_mangle_N", g) for g in scan.globals)
    return {"skeletons": sorted(skeletons), "methods": {k: sorted(v) for k, v in methods.items()},
            "pickle_globals": {k: sorted(v) for k, v in globs.items()}}


def _zip_members(data: bytes, where: str | os.PathLike[str], what: str) -> tuple[zipfile.ZipFile, str, list[zipfile.ZipInfo]]:
    try:
        zf = zipfile.ZipFile(io.BytesIO(data))
        infos = zf.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise CheckpointError(f"{where}: not {what} (not a zip archive: {exc})") from None
    roots = {i.filename.split("/", 1)[0] for i in infos}
    if len(roots) != 1 or any("/" not in i.filename for i in infos):
        zf.close()
        raise CheckpointError(f"{where}: not {what} (expected one root folder, got {sorted(roots)[:5]})")
    return zf, roots.pop() + "/", infos


def _read(zf: zipfile.ZipFile, info: zipfile.ZipInfo, where: str | os.PathLike[str], limit: int = 64 << 20) -> bytes:
    if info.file_size > limit:
        raise CheckpointError(f"{where}: refused: member {info.filename[:200]!r} declares {info.file_size} bytes "
                              f"(a predictor's code and pickles are below {limit} bytes)")
    try:
        return zf.read(info)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, NotImplementedError) as exc:
        raise CheckpointError(f"{where}: not a readable archive (member {info.filename[:200]!r}: {exc})") from None


def check_torchscript_archive(data: bytes, *, where: str | os.PathLike[str], export: Callable[[Any], bytes]) -> None:
    """Refuse a TorchScript file unless its code, pickles and members are what this exporter writes.

    Nothing in ``data`` is executed: code is parsed with :mod:`ast`, pickles are scanned with
    inert stubs (:func:`bemlearn.safe_load.scan_pickle`).  ``export`` is the exporter
    (:func:`bemlearn.export.torchscript.torchscript_bytes`) the allow-list is derived from.

    Raises:
        CheckpointError: not a zip archive; a member, class, method, statement or operator
            call this exporter does not write (e.g. an added ``__setstate__``, a foreign module);
            a pickle naming another global; a storage declaring more bytes than its payload.
    """
    allow = torchscript_allowlist(export)
    zf, root, infos = _zip_members(data, where, "a TorchScript file")
    with zf:
        sizes = {i.filename[len(root):]: i.file_size for i in infos}
        code_files = [r for r in sizes if r.startswith("code/") and r.endswith(".py")]
        for rel in sizes:
            if not any(p.fullmatch(rel) for p in _TS_MEMBERS):
                raise CheckpointError(f"{where}: {_REFUSED}: unexpected member {rel[:200]!r} (foreign code or data); {_REEXPORT}")
        if len(code_files) != 1 or "data.pkl" not in sizes:
            raise CheckpointError(f"{where}: {_REFUSED}: expected one bemlearn BEMPredictor code file and data.pkl, "
                                  f"got {sorted(code_files)[:5]}; {_REEXPORT}")
        for info in infos:
            rel = info.filename[len(root):]
            if rel in code_files:
                try:
                    text = _read(zf, info, where).decode()
                except UnicodeDecodeError:
                    raise CheckpointError(f"{where}: {_REFUSED}: {rel} is not UTF-8 text") from None
                code = normalized_script_code(text, where=where)
                if _digest(code.skeleton) not in allow.skeletons:
                    raise CheckpointError(f"{where}: {_REFUSED}: {rel} defines other classes or class attributes; {_REEXPORT}")
                extra = sorted(set(code.methods) - set(allow.methods))
                if extra:
                    raise CheckpointError(f"{where}: {_REFUSED}: {rel} defines method(s) {extra[:5]} (e.g. a __setstate__ "
                                          f"runs while loading); {_REEXPORT}")
                for method, dump in code.methods.items():
                    if _digest(dump) not in allow.methods[method]:
                        raise CheckpointError(f"{where}: {_REFUSED}: the code of method {method!r} in {rel} differs from "
                                              f"the exporter's; {_REEXPORT}")
            elif (kind := _pickle_kind(rel)) is not None:
                scan = scan_pickle(_read(zf, info, where), where=f"{where}: {rel}")
                foreign = sorted(g for g in scan.globals if _MANGLE.sub("___torch_mangle_N", g) not in allow.pickle_globals.get(kind, ()))
                if foreign or scan.other_ids:
                    raise CheckpointError(f"{where}: {_REFUSED}: {rel} names {(foreign or scan.other_ids)[0][:120]}; {_REEXPORT}")
                folder = "data/" if rel == "data.pkl" else "constants/"
                for storage, key, numel in scan.storages:
                    itemsize = STORAGE_ITEMSIZE.get(storage)
                    have = sizes.get(folder + key)
                    if itemsize is None or have is None or numel < 0 or numel * itemsize > have:
                        raise CheckpointError(f"{where}: refused: {rel} declares a {storage} of {numel} elements in "
                                              f"{folder}{key[:40]}, which holds {have} bytes")


@functools.cache
def pt2_allowlist(method_module: Callable[[Any, str], torch.nn.Module]) -> frozenset[str]:
    """The operators of the reference ``.pt2`` programs: ``forward`` and ``predict_full`` (whose
    operators include those of the mean-only and latent methods) exported with every flag on
    and with every flag off (each branch of the code is taken by one of the two); cached (:func:`_cache_file`)."""
    return frozenset(_cached("pt2-allowlist", functools.partial(_derive_pt2_allowlist, method_module))["operators"])


def _derive_pt2_allowlist(method_module: Callable[[Any, str], torch.nn.Module]) -> dict[str, Any]:
    base = reference_predictor()
    names = structural_flags()
    on = dict.fromkeys(names, True)
    off = dict.fromkeys(names, False)
    ops: set[str] = set()
    batch = torch.export.Dim("batch", min=1)
    for flags in (on, off):
        p = _with_flags(base, flags, flags).eval()
        for method, width in (("forward", p.n_bem), ("predict_full", p.n_full)):
            with torch.no_grad():
                program = torch.export.export(method_module(p, method), (torch.zeros(4, width, dtype=torch.float64),),
                                              dynamic_shapes={"x": {0: batch}}, strict=False)
            ops.update(f"torch.ops.{n.target}" for n in program.graph.nodes if n.op == "call_function")
    return {"operators": sorted(ops)}


#: Tokens of the symbolic sizes torch.export writes for a predictor (``s77``,
#: ``Symbol('s77', positive=True, integer=True)``, sums and products with integers).
_SYM_TOKEN = re.compile(r"\s+|\d+|[()+*,=-]|'[su]\d+'|[A-Za-z_]\w*")
#: The only names such a string may use: ``sympy.sympify`` evaluates it, so no other call is possible.
_SYM_NAMES = frozenset({"Symbol", "Integer", "Add", "Mul", "positive", "integer", "nonnegative", "True", "False"})


def _safe_symbolic(text: object) -> bool:
    if not isinstance(text, str) or not 0 < len(text) <= 300:
        return False
    tokens = _SYM_TOKEN.findall(text)
    if "".join(tokens) != text:
        return False
    return all(not (t[0].isalpha() or t[0] == "_") or t in _SYM_NAMES or re.fullmatch(r"[su]\d+", t) for t in tokens)


def _walk(node: Any, path: str = ""):
    if isinstance(node, dict):
        for k, v in node.items():
            yield path, k, v
            yield from _walk(v, f"{path}/{k}")
    elif isinstance(node, list):
        for v in node:
            yield from _walk(v, path)


def check_pt2_programs(programs: dict[str, bytes], *, where: str | os.PathLike[str],
                       names: Iterable[str], method_module: Callable[[Any, str], torch.nn.Module]) -> None:
    """Refuse ``.pt2`` programs (``models/<name>.json`` → bytes) with operators, guards or
    symbolic strings this exporter does not write (nothing is executed).  ``names`` are the
    program names the exporter writes (``PT2_PROGRAMS``), ``method_module`` its wrapper of one
    predictor method (the allow-list is derived by exporting it, :func:`pt2_allowlist`).

    Raises:
        CheckpointError: a program name outside ``PT2_PROGRAMS``; a node calling an operator the
            reference programs do not call (e.g. ``aten.from_file``); custom objects; guard
            code; a symbolic-shape string using names other than sympy's ``Symbol``, ``Integer``,
            ``Add``, ``Mul`` and symbols ``s<N>`` / ``u<N>``.
    """
    ops = pt2_allowlist(method_module)
    allowed = set(names)
    for name, raw in programs.items():
        if name not in allowed:
            raise CheckpointError(f"{where}: {_REFUSED}: unexpected program models/{name[:100]}.json; {_REEXPORT}")
        try:
            doc = json.loads(raw)
        except (ValueError, UnicodeDecodeError, RecursionError) as exc:
            raise CheckpointError(f"{where}: models/{name}.json is not JSON ({type(exc).__name__})") from None
        graph_module = doc.get("graph_module") if isinstance(doc, dict) else None
        graph = graph_module.get("graph") if isinstance(graph_module, dict) else None
        if not isinstance(graph, dict) or not isinstance(graph.get("nodes"), list):
            raise CheckpointError(f"{where}: models/{name}.json is not a torch.export program")
        for node in graph["nodes"]:
            target = node.get("target") if isinstance(node, dict) else None
            if target not in ops:
                raise CheckpointError(f"{where}: {_REFUSED}: models/{name}.json calls {str(target)[:120]!r}; {_REEXPORT}")
        if graph.get("custom_obj_values") or doc.get("guards_code"):
            raise CheckpointError(f"{where}: {_REFUSED}: models/{name}.json carries custom objects or guard code; {_REEXPORT}")
        symbols = [k for k in (doc.get("range_constraints") or {})]
        symbols += [v for _, k, v in _walk(doc) if k == "expr_str"]
        for text in symbols:
            if not _safe_symbolic(text):
                raise CheckpointError(f"{where}: {_REFUSED}: models/{name}.json holds the symbolic size {str(text)[:120]!r} "
                                      f"(torch would evaluate it); {_REEXPORT}")
