"""Loading files a user may have received (predictors, checkpoints, trajectories) without running code in them.

Python's ``pickle`` runs any callable a file names (``__reduce__``), so a shared ``.pt``,
``.pt2`` or ``.npz`` could run code the moment it is loaded.  Every bemlearn reader goes
through this module, which refuses pickled code by one rule per format:

- **torch.save files** (checkpoints, and the pickles inside a ``.pt2``):
  :func:`torch_load_weights` is ``torch.load(weights_only=True)``, whose unpickler
  builds tensors, containers and numbers only; anything else is a
  :class:`~bemlearn.errors.CheckpointError` that says so.
- **``.pt2`` archives** (``torch.export``): torch's own loader falls back to
  ``weights_only=False`` when the sample inputs do not load safely, unpickles "pickled"
  weights and constants without restriction, ``pickle.loads`` opaque objects and loads
  AOTInductor shared libraries.  :func:`read_pt2_archive` therefore checks the archive first
  (:func:`check_pt2_archive`): only the members a bemlearn predictor consists of (program
  JSON, raw tensor payloads, payload configs without ``use_pickle``, sample inputs that load
  with ``weights_only=True``, extra files); then it hands torch the very bytes it checked.
- **TorchScript ``.pt``**: ``torch.jit.load`` is C++ only; its unpickler resolves
  TorchScript classes and tensors and never calls Python (a pickled callable is an error).
  :func:`load_script_module` maps its errors to :class:`~bemlearn.errors.CheckpointError`.
- **``.npz``**: :func:`open_npz` is ``np.load(allow_pickle=False)``: object arrays are refused.

Refusing pickled *calls* is not enough for the predictor formats, which carry *code*:
TorchScript's ``code/`` files are compiled and their ``__setstate__`` runs on load, and a
``.pt2`` graph names operators (``aten.from_file`` opens any file) and holds strings torch
hands to ``sympy.sympify`` (an ``eval``) or turns into Python guards.  The helpers below read
such an archive without executing anything — :func:`scan_pickle` walks a pickle with every
global replaced by an inert stub, :func:`normalized_script_code` parses TorchScript code with
:mod:`ast` and abstracts its literals — so that :mod:`bemlearn.export.archive_check` can
compare the archive with what this version's exporter writes before torch sees it.

``tests/test_safe_load.py`` feeds each reader a tampered file whose pickle would create a
folder, and checks that the reader refuses it and the folder was not created.
"""

from __future__ import annotations

import ast
import io
import json
import os
import pickle
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bemlearn.errors import CheckpointError, MissingFileError

__all__ = ["torch_load_weights", "check_pt2_archive", "read_pt2_archive", "load_script_module", "open_npz",
           "PT2_MEMBERS", "PickleScan", "scan_pickle", "normalized_script_code", "ScriptCode", "STORAGE_ITEMSIZE"]

#: The members a bemlearn ``.pt2`` predictor consists of (paths below the archive's root folder).
PT2_MEMBERS: tuple[re.Pattern[str], ...] = tuple(re.compile(p) for p in (
    r"archive_format", r"archive_version", r"byteorder", r"version", r"\.data/version", r"\.data/serialization_id",
    r"models/[\w.-]+\.json",
    r"data/weights/[\w.-]+_weights_config\.json", r"data/weights/weight_\d+",
    r"data/constants/[\w.-]+_constants_config\.json", r"data/constants/tensor_\d+",
    r"data/sample_inputs/[\w.-]+\.pt",
    r"extra/[\w.-]+",
))


def torch_load_weights(source: str | os.PathLike[str] | bytes, *, where: str | os.PathLike[str], what: str = "a torch file") -> Any:
    """``torch.load(source, weights_only=True, map_location="cpu")``: tensors, containers and numbers only.

    Args:
        source: a file path or the bytes of a ``torch.save`` file.
        where: names the file in errors.
        what: what the file should be, for the error message (e.g. ``"a bemlearn checkpoint"``).

    Raises:
        CheckpointError: the file holds pickled objects other than tensors, containers and
            numbers (e.g. a ``__reduce__`` that would call a function), or is not a torch file.
    """
    import pickle

    import torch

    try:
        return torch.load(io.BytesIO(source) if isinstance(source, bytes) else source, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        named = re.search(r"GLOBAL (\S+)", str(exc))
        what_it_is = f"it names {named.group(1)[:120]}" if named else str(exc).strip().splitlines()[0][:200]
        raise CheckpointError(f"{where}: refused: the file holds pickled objects other than tensors, containers and numbers "
                              f"(loading it would run code; {what_it_is})") from None
    except Exception as exc:  # torch raises many types for a corrupt or foreign file
        raise CheckpointError(f"{where}: cannot be read as {what} ({type(exc).__name__}: {str(exc)[:300]})") from exc


def _pt2_payload_config(data: bytes, where: str) -> dict[str, Any]:
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{where}: not a JSON payload config ({exc})") from None
    config = doc.get("config") if isinstance(doc, dict) else None
    if not isinstance(config, dict):
        raise CheckpointError(f"{where}: expected a JSON object with a 'config' mapping")
    return config


def check_pt2_archive(data: bytes, *, where: str | os.PathLike[str]) -> None:
    """Refuse a ``.pt2`` archive from which ``torch.export`` would run pickled code or native libraries.

    Raises:
        CheckpointError: not a zip archive; members outside :data:`PT2_MEMBERS` (e.g.
            ``data/aotinductor/`` shared libraries, legacy pickled weight files, custom or
            opaque objects); a weight or constant marked ``use_pickle``; sample inputs that do
            not load with ``weights_only=True``.
    """
    try:
        zf = zipfile.ZipFile(io.BytesIO(data))
        names = zf.namelist()
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise CheckpointError(f"{where}: not a torch.export .pt2 archive ({exc})") from None
    with zf:
        roots = {n.split("/", 1)[0] for n in names}
        if len(roots) != 1 or any("/" not in n for n in names):
            raise CheckpointError(f"{where}: not a torch.export .pt2 archive (expected one root folder, got {sorted(roots)[:5]})")
        root = roots.pop() + "/"
        for name in names:
            rel = name[len(root):]
            if not rel or rel.endswith("/"):
                continue
            if not any(p.fullmatch(rel) for p in PT2_MEMBERS):
                raise CheckpointError(f"{where}: refused: unexpected member {rel[:200]!r} (a bemlearn predictor holds only "
                                      "program JSON, raw tensors, sample inputs and extra files; torch would load this one "
                                      "as pickled code or a native library)")
            if rel.endswith(("_weights_config.json", "_constants_config.json")):
                for key, meta in _pt2_payload_config(zf.read(name), f"{where}: {rel}").items():
                    path = meta.get("path_name", "") if isinstance(meta, dict) else ""
                    if not isinstance(meta, dict) or meta.get("use_pickle") or not re.fullmatch(r"(weight|tensor)_\d+", str(path)):
                        raise CheckpointError(f"{where}: refused: {rel} loads {str(key)[:100]!r} as a pickled object "
                                              f"({str(meta)[:200]}); a bemlearn predictor stores raw tensors only")
            elif rel.startswith("data/sample_inputs/"):
                torch_load_weights(zf.read(name), where=f"{where}: {rel}", what="torch.export sample inputs")


def read_pt2_archive(source: str | os.PathLike[str] | bytes, *, where: str | os.PathLike[str] | None = None):
    """``torch.export``'s ``load_pt2`` of the bytes of ``source`` (a path, or the archive's bytes) after
    :func:`check_pt2_archive` passed on them.

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        CheckpointError: refused by :func:`check_pt2_archive`, or torch cannot read it.
    """
    from torch.export.pt2_archive._package import load_pt2

    if isinstance(source, bytes):
        data, path = source, where or "<.pt2 bytes>"
    else:
        path = Path(source)
        if not path.is_file():
            raise MissingFileError(f"{path}: no such .pt2 predictor file")
        data = path.read_bytes()
    check_pt2_archive(data, where=path)
    try:
        return load_pt2(io.BytesIO(data))
    except Exception as exc:  # torch raises several types for foreign archives
        raise CheckpointError(f"{path}: not a torch.export .pt2 archive ({type(exc).__name__}: {str(exc)[:300]})") from exc


def load_script_module(source: str | os.PathLike[str] | bytes, extra_files: dict[str, Any] | None = None, *,
                       where: str | os.PathLike[str] | None = None):
    """``torch.jit.load(source, map_location="cpu")`` (C++ only: no Python unpickling) with named errors;
    ``source`` is a path or the bytes of a TorchScript file (``where`` names it in errors).

    Raises:
        MissingFileError: (a FileNotFoundError) no such file.
        CheckpointError: not a TorchScript archive, or its pickles name anything but
            TorchScript classes and tensors.
    """
    import warnings

    import torch

    f: io.BytesIO | str
    if isinstance(source, bytes):
        path, f = where or "<TorchScript bytes>", io.BytesIO(source)
    else:
        path = Path(source)
        if not path.is_file():
            raise MissingFileError(f"{path}: no such TorchScript predictor file")
        f = str(path)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*torch\.jit\..* is deprecated", category=DeprecationWarning)
            return torch.jit.load(f, map_location="cpu", _extra_files=extra_files if extra_files is not None else {})
    except Exception as exc:  # torch raises RuntimeError and others for foreign or truncated files
        raise CheckpointError(f"{path}: not a TorchScript file ({type(exc).__name__}: {str(exc)[:300]})") from exc


def open_npz(path: str | os.PathLike[str]):
    """``np.load(path, allow_pickle=False)``: an ``NpzFile`` whose object arrays are refused when read."""
    import numpy as np

    return np.load(path, allow_pickle=False)


#: Bytes per element of the storage classes a TorchScript / torch.save pickle names.
STORAGE_ITEMSIZE = {"DoubleStorage": 8, "FloatStorage": 4, "HalfStorage": 2, "BFloat16Storage": 2, "LongStorage": 8,
                    "IntStorage": 4, "ShortStorage": 2, "CharStorage": 1, "ByteStorage": 1, "BoolStorage": 1,
                    "ComplexDoubleStorage": 16, "ComplexFloatStorage": 8}


@dataclass
class PickleScan:
    """What a pickle names, read without running it.

    Attributes:
        globals: every ``module name`` pair the pickle looks up (``GLOBAL`` / ``STACK_GLOBAL``).
        storages: ``(storage class name, record key, element count)`` of every persistent
            ``('storage', …)`` id (TorchScript and ``torch.save`` tensor payloads).
        other_ids: persistent ids of any other form (refused by the callers).
    """

    globals: set[str] = field(default_factory=set)
    storages: list[tuple[str, str, int]] = field(default_factory=list)
    other_ids: list[str] = field(default_factory=list)


class _Stub:
    """What every global of a scanned pickle becomes: constructible from anything, and inert."""

    qualname = ""

    def __new__(cls, *args: Any, **kwargs: Any) -> _Stub:
        return object.__new__(cls)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __setstate__(self, state: Any) -> None:
        pass

    def __call__(self, *args: Any, **kwargs: Any) -> _Stub:
        return _Stub()

    def __setitem__(self, key: Any, value: Any) -> None:
        pass

    def append(self, item: Any) -> None:
        pass

    def extend(self, items: Any) -> None:
        pass


class _ScanUnpickler(pickle.Unpickler):
    def __init__(self, data: bytes, scan: PickleScan) -> None:
        super().__init__(io.BytesIO(data))
        self.scan = scan

    def find_class(self, module: str, name: str) -> Any:
        qualname = f"{module} {name}"
        self.scan.globals.add(qualname)
        return type("Stub", (_Stub,), {"qualname": qualname})

    def persistent_load(self, pid: Any) -> Any:
        if (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage" and isinstance(pid[1], type)
                and issubclass(pid[1], _Stub) and isinstance(pid[2], str) and isinstance(pid[4], int)):
            self.scan.storages.append((pid[1].qualname.split(" ", 1)[-1], pid[2], pid[4]))
        else:
            self.scan.other_ids.append(repr(pid)[:100])
        return _Stub()


def scan_pickle(data: bytes, *, where: str | os.PathLike[str]) -> PickleScan:
    """The globals and storages a pickle names, found by unpickling it with every global replaced
    by an inert stub (nothing the file names is imported or called).

    Raises:
        CheckpointError: the bytes are not a pickle.
    """
    scan = PickleScan()
    try:
        _ScanUnpickler(data, scan).load()
    except Exception as exc:  # noqa: BLE001 - a malformed pickle raises many types (UnpicklingError, EOFError, …)
        raise CheckpointError(f"{where}: not a readable pickle ({type(exc).__name__}: {str(exc)[:200]})") from None
    return scan


#: String literals kept verbatim when code is normalized: dotted names (an exception class,
#: a dtype's name) may be looked up by torch, so they must be the exporter's own.
_QUALIFIED_NAME = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+")
_MANGLE = re.compile(r"___torch_mangle_\d+")


class _NormalizeLiterals(ast.NodeTransformer):
    """Numbers and free text become placeholders: the values a predictor legitimately varies in."""

    def visit_Constant(self, node: ast.Constant) -> ast.AST:
        value = node.value
        if isinstance(value, bool) or value is None or value is Ellipsis:
            return node
        if isinstance(value, (int, float, complex)):
            return ast.copy_location(ast.Name(id="__number__", ctx=ast.Load()), node)
        if isinstance(value, str) and not _QUALIFIED_NAME.fullmatch(value):
            return ast.copy_location(ast.Name(id="__text__", ctx=ast.Load()), node)
        return node


_EXPRESSION_FIELDS = {ast.If: ("test",), ast.While: ("test",), ast.For: ("iter",), ast.Assign: ("value",),
                      ast.Expr: ("value",), ast.Return: ("value",), ast.AugAssign: ("value",)}


class _Substitute(ast.NodeTransformer):
    def __init__(self, name: str, value: ast.expr) -> None:
        self.name, self.value, self.done = name, value, False

    def visit_Name(self, node: ast.Name) -> ast.AST:
        if not self.done and node.id == self.name and isinstance(node.ctx, ast.Load):
            self.done = True
            return self.value
        return node


def _inline_temporaries(func: ast.FunctionDef | ast.AsyncFunctionDef) -> None:
    """Put back every temporary ``t = e`` that is assigned once and read once, in the next statement.

    TorchScript's printer breaks a long expression into such temporaries, so where they appear
    depends on how long the literals are (a float's digits, a column name); with them inlined,
    the same code gives the same tree whatever its literals.
    """
    stores: dict[str, int] = {}
    loads: dict[str, int] = {}
    for n in ast.walk(func):
        if isinstance(n, ast.Name):
            counts = stores if isinstance(n.ctx, ast.Store) else loads
            counts[n.id] = counts.get(n.id, 0) + 1

    def process(body: list[ast.stmt]) -> None:
        for stmt in body:
            for name in ("body", "orelse", "finalbody"):
                block = getattr(stmt, name, None)
                if isinstance(block, list) and block and isinstance(block[0], ast.stmt):
                    process(block)
        for i in range(len(body) - 2, -1, -1):
            stmt, nxt = body[i], body[i + 1]
            if not (isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 and isinstance(stmt.targets[0], ast.Name)):
                continue
            name = stmt.targets[0].id
            if stores.get(name) != 1 or loads.get(name) != 1:
                continue
            sub = _Substitute(name, stmt.value)
            for fieldname in _EXPRESSION_FIELDS.get(type(nxt), ()):
                setattr(nxt, fieldname, sub.visit(getattr(nxt, fieldname)))
            if sub.done:
                del body[i]

    process(func.body)


def _canonical_locals(func: ast.FunctionDef | ast.AsyncFunctionDef) -> ast.FunctionDef | ast.AsyncFunctionDef:
    """Rename the arguments, assigned names and ``CONSTANTS.c<i>`` tensors of ``func`` by order of
    appearance (TorchScript numbers its temporaries and constants across a whole file, so the same
    method gets other names after another one); temporaries are inlined first (:func:`_inline_temporaries`)."""
    _inline_temporaries(func)
    local = {a.arg for a in func.args.args + func.args.kwonlyargs}
    local |= {n.id for n in ast.walk(func) if isinstance(n, ast.Name) and isinstance(n.ctx, (ast.Store, ast.Del))}
    names: dict[str, str] = {}
    constants: dict[str, str] = {}
    for node in ast.walk(func):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "CONSTANTS":
            node.attr = constants.setdefault(node.attr, f"__constant{len(constants)}__")
        elif isinstance(node, ast.arg):
            node.arg = names.setdefault(node.arg, f"__local{len(names)}__")
        elif isinstance(node, ast.Name) and node.id in local:
            node.id = names.setdefault(node.id, f"__local{len(names)}__")
    return func


@dataclass(frozen=True)
class ScriptCode:
    """TorchScript code normalized for comparison (:func:`normalized_script_code`).

    Attributes:
        skeleton: the module with every method removed (class name, bases, class attributes).
        methods: method name → its normalized syntax tree (``ast.dump``).
    """

    skeleton: str
    methods: dict[str, str]


def normalized_script_code(text: str, *, where: str | os.PathLike[str]) -> ScriptCode:
    """Parse TorchScript's serialized code (Python syntax) without running it; numbers become
    ``__number__``, strings other than dotted names ``__text__``, ``___torch_mangle_N`` suffixes
    one name, local names are numbered by appearance.  Two exports that differ only in tensor data, sizes, column names and messages
    give equal results.

    Raises:
        CheckpointError: the text does not parse, or defines anything but one class of methods.
    """
    try:
        tree = _NormalizeLiterals().visit(ast.parse(text))
    except (SyntaxError, ValueError, RecursionError, MemoryError) as exc:
        raise CheckpointError(f"{where}: refused: its TorchScript code does not parse ({type(exc).__name__})") from None
    methods: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            kept = []
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    if item.name in methods:
                        raise CheckpointError(f"{where}: refused: its TorchScript code defines {item.name!r} twice")
                    methods[item.name] = _MANGLE.sub("___torch_mangle_N", ast.dump(_canonical_locals(item)))
                else:
                    kept.append(item)
            node.body = kept
    return ScriptCode(skeleton=_MANGLE.sub("___torch_mangle_N", ast.dump(tree)), methods=methods)
