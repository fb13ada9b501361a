"""Compiling an MJCF file: its numbers checked first, big models compiled where a signal can stop them.

* **Non-finite numbers.**  MuJoCo reads ``mass="nan"`` as "no mass given" and computes one from
  the geom's density (a model with a NaN mass loaded as 0.279 kg); an ``inf`` size or gain may
  compile as well.  :func:`check_finite_attributes` reads the file (and the files it
  ``<include>``\\ s) as XML, without compiling, and refuses any physical attribute
  (:data:`NUMERIC_ATTRIBUTES`: masses, inertias, sizes, positions, ranges, gains, damping, …)
  holding NaN or ±inf, naming the file, the element and the attribute.  One exception: a joint's
  ``range`` may be ``"-inf inf"`` (a joint without limits, e.g. a wheel;
  :class:`~bemlearn.robots.MujocoRobot` treats it as unlimited); NaN is refused there too.
* **Signals.**  A Python signal handler runs only between bytecodes, so SIGINT / SIGTERM sent
  while MuJoCo's C compiler works on a model of 10⁴–10⁵ bodies waited for the compiler (55 s,
  or > 10 min).  :func:`compile_mjcf` compiles files larger than :data:`CHILD_COMPILE_BYTES`
  in a forked child process while the parent waits on a pipe in 0.2 s steps: a signal ends the
  wait at once, the child is killed and the command cleans up as after any interruption.  The
  compiled model comes back pickled (``MjModel`` pickles through MuJoCo's binary model format).
"""

from __future__ import annotations

import os
import pickle
import select
import signal
import threading
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

import mujoco

from bemlearn.errors import RobotModelError

__all__ = ["compile_mjcf", "declared_spec", "check_finite_attributes", "NUMERIC_ATTRIBUTES", "CHILD_COMPILE_BYTES"]

#: MJCF files at least this large (bytes, includes counted) compile in a child process.
CHILD_COMPILE_BYTES = 256 * 1024

#: The MJCF attributes that hold physical numbers (any element): each must be finite.
NUMERIC_ATTRIBUTES = frozenset({
    "mass", "inertia", "diaginertia", "fullinertia", "density", "size", "fromto", "pos", "quat", "euler", "axisangle",
    "xyaxes", "zaxis", "axis", "range", "ctrlrange", "forcerange", "actuatorfrcrange", "lengthrange", "gear", "gainprm",
    "biasprm", "dynprm", "kp", "kv", "ki", "damping", "armature", "frictionloss", "stiffness", "springref", "springdamper",
    "ref", "friction", "margin", "gap", "solref", "solimp", "solreflimit", "solimplimit", "solreffriction",
    "solimpfriction", "timestep", "gravity", "wind", "magnetic", "viscosity", "impratio", "tolerance", "data",
    "cranklength", "timeconst", "scale", "radius", "width", "height", "polycoef", "user", "noise", "cutoff",
})
_NON_FINITE = frozenset({"nan", "+nan", "-nan", "inf", "+inf", "-inf", "infinity", "+infinity", "-infinity"})
_MAX_INCLUDE_DEPTH = 20


def _describe(element: ET.Element, attr: str) -> str:
    name = element.get("name")
    named = f' name="{name}"' if name else ""
    value = element.get(attr, "")[:80]
    return f'<{element.tag}{named} {attr}="{value}">'


def _files(path: Path, depth: int = 0) -> list[tuple[Path, ET.Element]]:
    """The parsed file and, recursively, the files its ``<include file=…>`` elements name."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError, ValueError):   # MuJoCo's compiler reports a malformed file in its own words
        return []
    out = [(path, root)]
    if depth < _MAX_INCLUDE_DEPTH:
        for inc in root.iter("include"):
            name = inc.get("file")
            target = path.parent / name if name else None
            if target is not None and target.is_file():
                out += _files(target, depth + 1)
    return out


def check_finite_attributes(path: str | os.PathLike[str]) -> None:
    """Refuse an MJCF whose physical attributes (:data:`NUMERIC_ATTRIBUTES`) hold NaN or ±inf.

    Raises:
        RobotModelError: ``FILE: <geom name="arm" mass="nan">: mass is not finite; expected finite numbers``.
    """
    for file, root in _files(Path(path)):
        for element in root.iter():
            for attr, value in element.attrib.items():
                if attr == "range" and element.tag == "joint" and _unbounded_range(value):
                    continue
                if attr in NUMERIC_ATTRIBUTES and any(tok.lower() in _NON_FINITE for tok in value.split()):
                    raise RobotModelError(f"{file}: {_describe(element, attr)}: {attr} is not finite (NaN or inf); "
                                          "expected finite numbers")


def _unbounded_range(value: str) -> bool:
    """True for a joint range whose two ends are −∞ and +∞ (a joint without limits)."""
    tokens = [tok.lower().lstrip("+") for tok in value.split()]
    return len(tokens) == 2 and tokens[0] in ("-inf", "-infinity") and tokens[1] in ("inf", "infinity")


def _size(path: Path) -> int:
    try:
        return sum(f.stat().st_size for f, _ in _files(path)) if path.stat().st_size < CHILD_COMPILE_BYTES else path.stat().st_size
    except OSError:
        return 0


def compile_mjcf(path: str | os.PathLike[str], custom: Mapping[str, list[float] | str] | None = None) -> mujoco.MjModel:
    """``mujoco.MjModel.from_xml_path(path)``, after :func:`check_finite_attributes`; in a child process
    for a large file (module docstring), so that SIGINT / SIGTERM are not held up by the compiler.

    ``custom``: ``<custom>`` elements declared beside the file (a config's ``coordinates:`` block,
    :func:`bemlearn.robots.coordinates.custom_entries`), replacing the file's elements of the same name;
    the model is then compiled through ``mujoco.MjSpec``.

    Raises:
        RobotModelError: non-finite attributes, or MuJoCo cannot compile the model.
        KeyboardInterrupt: SIGINT or SIGTERM during the compilation (the child is killed).
    """
    path = Path(path)
    check_finite_attributes(path)
    custom = dict(custom or {})
    if (_size(path) < CHILD_COMPILE_BYTES or not hasattr(os, "fork")
            or threading.current_thread() is not threading.main_thread()):
        return _compile(path, custom)
    return _compile_in_child(path, custom)


def declared_spec(path: str | os.PathLike[str], custom: Mapping[str, list[float] | str]) -> mujoco.MjSpec:
    """``mujoco.MjSpec`` of the MJCF at ``path`` with the ``<custom>`` elements ``custom`` declared
    (:func:`bemlearn.robots.coordinates.apply_custom`)."""
    from bemlearn.robots.coordinates import apply_custom

    spec = mujoco.MjSpec.from_file(str(path))
    apply_custom(spec, custom)
    return spec


def _build(path: Path, custom: Mapping[str, list[float] | str]) -> mujoco.MjModel:
    return declared_spec(path, custom).compile() if custom else mujoco.MjModel.from_xml_path(str(path))


def _compile(path: Path, custom: Mapping[str, list[float] | str]) -> mujoco.MjModel:
    try:
        return _build(path, custom)
    except ValueError as exc:
        raise RobotModelError(f"{path}: MuJoCo could not load the model: {exc}") from exc


def _compile_in_child(path: Path, custom: Mapping[str, list[float] | str]) -> mujoco.MjModel:
    from bemlearn.child_processes import die_with_parent
    from bemlearn.interrupts import check_interrupt

    read_fd, write_fd = os.pipe()
    parent = os.getpid()
    pid = os.fork()
    if pid == 0:  # the child: compile, send the model (or MuJoCo's message) back, exit without cleanup
        code = 1
        try:
            os.close(read_fd)
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, signal.SIG_DFL)
            die_with_parent(parent)
            try:
                payload = pickle.dumps(("model", _build(path, custom)))
            except ValueError as exc:
                payload = pickle.dumps(("error", str(exc)))
            with os.fdopen(write_fd, "wb") as fh:
                fh.write(payload)
            code = 0
        finally:
            os._exit(code)
    os.close(write_fd)
    chunks: list[bytes] = []
    try:
        while True:   # short waits: a signal handler runs between them (or interrupts one)
            ready, _, _ = select.select([read_fd], [], [], 0.2)
            check_interrupt()
            if ready:
                data = os.read(read_fd, 1 << 20)
                if not data:
                    break
                chunks.append(data)
    except BaseException:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        raise
    finally:
        os.close(read_fd)
    _, status = os.waitpid(pid, 0)
    if not chunks:
        raise RobotModelError(f"{path}: MuJoCo's compiler ended without a model (child status {status})")
    kind, value = pickle.loads(b"".join(chunks))   # written by our own child above, not read from a file
    if kind == "error":
        raise RobotModelError(f"{path}: MuJoCo could not load the model: {value}")
    return value
