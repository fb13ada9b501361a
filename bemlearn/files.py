"""Writing outputs without losing a user's work: atomic writes, overwrite guard, run folders.

- :func:`atomic_path` yields a temporary path in the target's folder; when the block ends
  normally the file is flushed to disk (``fsync``) and renamed over the target
  (``os.replace``, atomic on POSIX), so a killed process leaves either the old file or the
  new one at the target path, never a half-written one.  Writers that want a path
  (``torch.save``, ``np.savez``, ``fig.savefig``) write to the yielded path.
- :func:`check_outputs` refuses to replace existing files unless ``force``
  (:class:`~bemlearn.errors.OutputExistsError` listing them and saying ``use --force``).
- :func:`new_run_dir` names a new timestamped run folder ``runs/<name>-YYYYmmdd-HHMMSS``
  that does not exist yet (``create=True`` creates it exclusively, so two commands never
  share it); :func:`created_dir` creates a folder and removes it again if the command that
  created it fails.  Commands claim their outputs with :func:`bemlearn.outputs.claim_outputs`.
- A write that fails because the disk is full or read-only (``ENOSPC``, ``EDQUOT``,
  ``EROFS``, ``EACCES``, ``EFBIG``, ``EIO``) becomes one :class:`~bemlearn.errors.EnvironmentProblem`
  naming the file, with no temporary left behind (:func:`write_problem`).
  :func:`atomic_write_files` writes a set of files all or none (each temporary written and
  synced first, then renamed), after :func:`check_free_space` found room for all of them.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

from bemlearn.errors import EnvironmentProblem, MissingFileError, OutputExistsError

__all__ = [
    "atomic_path",
    "atomic_write_text",
    "atomic_write_bytes",
    "check_outputs",
    "existing_outputs",
    "file_sha256",
    "new_run_dir",
    "created_dir",
    "check_writable",
    "check_free_space",
    "atomic_write_files",
    "write_problem",
    "first_new_folder",
    "INTERNAL_PREFIX",
]

#: Names bemlearn keeps inside an output folder for itself (lock file, backups): never an output.
INTERNAL_PREFIX = ".bemlearn-"

#: ``errno`` values of a write that failed because of the machine, not the program.
WRITE_ERRNOS = {errno.ENOSPC: "no space left on device", errno.EROFS: "read-only file system",
                errno.EACCES: "permission denied", errno.EPERM: "operation not permitted",
                errno.EFBIG: "file too large", errno.EIO: "input/output error"}
if hasattr(errno, "EDQUOT"):
    WRITE_ERRNOS[errno.EDQUOT] = "disk quota exceeded"


def write_problem(path: str | os.PathLike[str], exc: OSError) -> EnvironmentProblem | None:
    """The :class:`EnvironmentProblem` for a write of ``path`` that failed with ``exc``, or ``None``
    when ``exc`` is not a full / read-only / unwritable disk (a bug or a missing file stays itself)."""
    if exc.errno not in WRITE_ERRNOS:
        return None
    name = errno.errorcode.get(exc.errno, str(exc.errno))
    return EnvironmentProblem(f"cannot write {path}: {WRITE_ERRNOS[exc.errno]} ({name}); "
                              f"nothing was written there and no temporary file was left")

log = logging.getLogger(__name__)


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path for ``path``; on success fsync it and rename it to ``path``.

    The temporary file has ``path``'s own name inside a hidden folder beside it
    (``.<name>.tmp-<pid>-<n>/<name>``), so writers that pick the format from the suffix
    (``savefig``, ``np.savez``) or name an archive after the file (``torch.jit.save``) see
    the real name, and the rename stays on one file system.  On any exception (or Ctrl-C)
    the temporary folder is removed and ``path`` is left as it was.  Parent folders are
    created.
    """
    path = Path(path)
    tmp_dir = path.parent / f".{path.name}.tmp-{os.getpid()}-{time.monotonic_ns() % 10**9}"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp_dir.mkdir()
    except OSError as exc:
        raise (write_problem(path, exc) or exc) from None
    tmp = tmp_dir / path.name
    try:
        yield tmp
        if not tmp.is_file():
            raise MissingFileError(f"{path}: the writer did not create the temporary file {tmp}")
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except OSError as exc:  # a full or read-only disk: one clear error (the temporary is removed below)
        problem = write_problem(path, exc)
        if problem is None:
            raise
        raise problem from None
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


def _write_data(path: Path, data: bytes) -> None:
    """The one primitive that writes bytes bemlearn holds in memory to a (temporary) file, synced."""
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`); returns ``path``."""
    with atomic_path(path) as tmp:
        _write_data(tmp, data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_path`); returns ``path``."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def check_free_space(sizes: Mapping[str | os.PathLike[str], int], *, margin: int = 1 << 16) -> None:
    """Fail before writing when the file systems of ``sizes``' paths lack room for them.

    Args:
        sizes: path → bytes it will take (paths on one file system are added up).
        margin: bytes kept free besides (metadata, the rename).

    Raises:
        EnvironmentProblem: naming the paths, the bytes needed and the bytes free.
    """
    need: dict[int, list] = {}
    for path, size in sizes.items():
        probe = Path(path).parent
        while not probe.exists() and probe.parent != probe:
            probe = probe.parent
        try:
            dev = os.stat(probe).st_dev
        except OSError:
            continue
        entry = need.setdefault(dev, [probe, 0, []])
        entry[1] += int(size)
        entry[2].append(str(path))
    for probe, total, paths in need.values():
        try:
            free = shutil.disk_usage(probe).free
        except OSError:  # pragma: no cover - no statvfs: the write itself will tell
            continue
        if free < total + margin:
            raise EnvironmentProblem(f"cannot write {', '.join(paths)}: {total / 2**20:.1f} MiB needed, {free / 2**20:.1f} MiB "
                                     f"free on the disk of {probe} (no space left on device); nothing was written")


def atomic_write_files(files: Mapping[str, bytes] | Mapping[Path, bytes] | Mapping[str | os.PathLike[str], bytes]) -> list[Path]:
    """Write several files all or none: room is checked (:func:`check_free_space`), every temporary
    is written and synced (one :func:`atomic_path` per file), and only then are they renamed over
    their targets; returns the paths.

    Raises:
        EnvironmentProblem: no room, or a full / read-only disk during the writes (nothing replaced,
            no temporary left).
    """
    items = [(Path(p), data) for p, data in files.items()]
    check_free_space({p: len(d) for p, d in items})
    with contextlib.ExitStack() as stack:
        # one atomic_path per file, entered last-first so that on a normal exit the renames run in
        # the given order; an error while writing unwinds them all with nothing renamed
        temporaries = [stack.enter_context(atomic_path(p)) for p, _ in reversed(items)][::-1]
        for (path, data), tmp in zip(items, temporaries):
            try:
                _write_data(tmp, data)
            except OSError as exc:   # named after the file that failed, not the first of the set
                raise (write_problem(path, exc) or exc) from None
    return [p for p, _ in items]


def existing_outputs(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """The entries of ``paths`` that exist (files, or folders holding more than bemlearn's own lock and backups)."""
    found = []
    for p in map(Path, paths):
        if p.is_dir():
            if any(not c.name.startswith(INTERNAL_PREFIX) for c in p.iterdir()):
                found.append(p)
        elif p.exists() or p.is_symlink():
            found.append(p)
    return found


def check_outputs(paths: Iterable[str | os.PathLike[str]], force: bool = False, *, what: str = "") -> list[Path]:
    """Refuse to replace existing outputs unless ``force``; returns the existing ones.

    Raises:
        OutputExistsError: some of ``paths`` exist (a folder counts when it is not empty)
            and ``force`` is false; the message lists them and says ``use --force``.
    """
    found = existing_outputs(paths)
    if found and not force:
        shown = ", ".join(str(p) for p in found[:8]) + (f" and {len(found) - 8} more" if len(found) > 8 else "")
        head = f"{what}: " if what else ""
        raise OutputExistsError(f"{head}would overwrite {shown}; use --force to replace")
    return found


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 (64 lowercase hex digits) of the file's bytes, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def new_run_dir(name: str, *, root: str | os.PathLike[str] = "runs", now: float | None = None, create: bool = False) -> Path:
    """``<root>/<name>-YYYYmmdd-HHMMSS`` that does not exist yet (``-2``, ``-3``, … appended if it does).

    With ``create`` the folder is created, exclusively (``mkdir`` fails on an existing folder,
    atomically): two commands started in the same second get two folders.  Without it the
    folder is not created (see :func:`created_dir`).
    """
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    base = Path(root) / f"{name}-{stamp}"
    path, k = base, 1
    if create:
        try:
            Path(root).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise (write_problem(root, exc) or exc) from None
    while True:
        if not create:
            if not path.exists():
                return path
        else:
            try:
                path.mkdir()
                return path
            except FileExistsError:
                pass
            except OSError as exc:
                raise (write_problem(path, exc) or exc) from None
        k += 1
        path = base.with_name(f"{base.name}-{k}")


def check_writable(folder: str | os.PathLike[str], *, what: str = "--out") -> None:
    """Fail fast when ``folder`` (or its nearest existing ancestor) cannot be written.

    Raises:
        EnvironmentProblem: the folder is a file, or the user cannot create files there.
    """
    folder = Path(folder)
    probe = folder
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise EnvironmentProblem(f"{what}: {probe} is a file, expected a folder")
    try:  # a real probe: os.access says yes to root even on read-only file systems
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as exc:
        raise EnvironmentProblem(f"{what}: cannot write in {probe} ({exc.strerror or exc})") from None


@contextlib.contextmanager
def created_dir(folder: str | os.PathLike[str], *, keep_on_interrupt: Iterable[str] | None = None) -> Iterator[Path]:
    """Create ``folder`` (and parents); if the block raises an ``Exception``, remove what was created.

    A folder (or any parent) that existed before is kept, with the files the block wrote
    in it.  Ctrl-C (``KeyboardInterrupt``) keeps the new folder when ``keep_on_interrupt``
    is ``None`` or names a file the block wrote there (e.g. ``checkpoint.pt``: an
    interrupted command writes its best state on purpose), and removes it otherwise.
    """
    folder = Path(folder)
    first_new = first_new_folder(folder)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        yield folder
    except KeyboardInterrupt:
        keep = keep_on_interrupt is None or any((folder / name).exists() for name in keep_on_interrupt)
        if first_new is not None and not keep:
            shutil.rmtree(first_new, ignore_errors=True)
        raise
    except Exception:
        if first_new is not None:
            shutil.rmtree(first_new, ignore_errors=True)
            log.info("removed %s after the failure", first_new)
        raise


def first_new_folder(folder: str | Path) -> Path | None:
    """The outermost of ``folder`` and its parents that does not exist yet (``None``: it exists): what a
    command that creates ``folder`` must remove to leave nothing behind."""
    first = None
    p = Path(folder)
    while not p.exists():
        first = p
        if p.parent == p:
            break
        p = p.parent
    return first
