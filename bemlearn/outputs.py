"""Claiming a command's outputs: one lock per folder, and a failed command leaves them as they were.

Every bemlearn command that writes files runs its work inside :func:`claim_outputs`, which

1. **creates the folder atomically** when it does not exist: a default folder
   ``runs/<name>-YYYYmmdd-HHMMSS`` is created with an exclusive ``mkdir`` (``-2``, ``-3``, …
   when taken), so two commands started in the same second never share it; an explicit one
   too, and a command that finds it created meanwhile by another treats it as existing;
2. **locks the folder** (``<folder>/.bemlearn-lock``, ``fcntl.flock``): a second command
   writing the same folder fails at once with :class:`~bemlearn.errors.OutputBusyError`
   naming the first one (its PID and command line).  Of two ``train --out SAME`` started
   together exactly one runs;
3. **checks the outputs under the lock** (``entries``: the files or subfolders the command
   writes, or ``None`` for the whole folder, a run folder): existing ones need ``force`` (or
   ``resume``), else :class:`~bemlearn.errors.OutputExistsError`;
4. **snapshots what it will replace**: the existing entries are hard-linked (copied where
   links are impossible) into ``<folder>/.bemlearn-backup-<pid>/``.  Every bemlearn writer
   replaces files by renaming a new file over them (:func:`bemlearn.files.atomic_path`), so
   the linked originals stay untouched;
5. on success drops the snapshot; when the block raises **before it produced anything worth
   keeping** (an error, a full disk, Ctrl-C or SIGTERM before any ``keep`` file was written)
   it **restores** the entries from the snapshot (new ones removed, old ones moved back) or,
   for a folder it created, removes the folder: never a mix of two runs (a new
   ``config.yaml`` beside an old checkpoint, a new checkpoint beside an old report).
   A failure or interruption **after** the command wrote one of its ``keep`` files (a
   collected ``data.npz``, a trained ``checkpoint.pt``) keeps what it produced: the new
   files stay, the old run's files it had not rewritten yet are removed (with ``--force``;
   with ``--resume`` they are the same run's and stay), and a warning names the folder and
   what it holds.  The rule is :func:`worth_keeping`, the one place that decides.

A command killed with SIGKILL (or a second Ctrl-C, which exits at once) leaves its lock file
holding its record; the folder is then *marked incomplete*.  The next command that claims the
folder restores the snapshot the record names (logging a warning), or, for a folder the killed
command had created, reports it as an incomplete run that only ``--force`` replaces.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

from bemlearn.errors import ArgumentError, EnvironmentProblem, OutputBusyError, OutputExistsError
from bemlearn.files import INTERNAL_PREFIX, check_writable, first_new_folder, new_run_dir, write_problem

try:  # POSIX
    import fcntl
except ImportError:  # pragma: no cover - Windows: the lock degrades to the record's PID
    fcntl = None  # type: ignore[assignment]  # checked before every use

__all__ = ["claim_outputs", "folder_lock", "worth_keeping", "LOCK_NAME", "BACKUP_PREFIX"]

log = logging.getLogger(__name__)

#: The lock file (and record of the command writing the folder) inside an output folder.
LOCK_NAME = f"{INTERNAL_PREFIX}lock"
#: Prefix of the snapshot folder inside an output folder.
BACKUP_PREFIX = f"{INTERNAL_PREFIX}backup-"

_held: dict[str, list] = {}   # real path of a lock file → [fd, depth, exclusive, record]


def _read_record(fd: int) -> dict | None:
    os.lseek(fd, 0, os.SEEK_SET)
    raw = os.read(fd, 1 << 16)
    if not raw.strip():
        return None
    try:
        doc = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        return None
    return doc if isinstance(doc, dict) else None


def _write_record(fd: int, record: dict) -> None:
    data = json.dumps(record).encode()
    os.ftruncate(fd, 0)
    os.lseek(fd, 0, os.SEEK_SET)
    os.write(fd, data)
    os.fsync(fd)


def _describe(record: dict | None) -> str:
    if not record:
        return "another bemlearn command"
    started = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(record.get("started", 0)))
    return f"`{str(record.get('command', 'bemlearn'))[:200]}` (pid {record.get('pid')}, started {started})"


def _pid_alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except (OSError, ValueError, TypeError):
        return False
    return True


def _acquire(path: Path, *, exclusive: bool, folder: Path) -> tuple[int, dict | None]:
    """Lock the file ``path`` (created if missing) without waiting; returns its fd and the record it holds.

    Raises:
        OutputBusyError: another process holds a conflicting lock.
    """
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise (write_problem(path, exc) or exc) from None
        busy = False
        try:
            if fcntl is not None:
                fcntl.flock(fd, (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB)
            else:  # pragma: no cover - no flock: a live PID in the record holds the file
                other = _read_record(fd)
                busy = bool(other and other.get("pid") != os.getpid() and _pid_alive(other.get("pid")))
        except BlockingIOError:
            busy = True
        if busy:
            other = _read_record(fd)
            os.close(fd)
            raise OutputBusyError(f"{folder}: {_describe(other)} is writing there right now; "
                                  "wait for it to finish or choose another output") from None
        try:   # the file locked must still be the one at the path (its last holder may have removed it)
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            return fd, _read_record(fd)
        os.close(fd)


def _release(path: Path, fd: int, *, exclusive: bool) -> None:
    """Unlock; the file is removed when no other process holds it (a shared lock is first upgraded, if free)."""
    try:
        if not exclusive and fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:   # others still hold it shared: leave the file to them
                return
        with contextlib.suppress(OSError):
            if os.path.samestat(os.fstat(fd), os.stat(path)):
                os.unlink(path)
    finally:
        os.close(fd)


@contextlib.contextmanager
def _locked(path: Path, *, exclusive: bool, folder: Path, record: dict | None) -> Iterator[dict | None]:
    """Hold the lock file ``path`` for the block (re-entrant in one process); yields the record a killed
    holder left in it (``None`` if none, or when this process holds it already)."""
    key = os.path.realpath(path)
    if key in _held:
        _held[key][1] += 1
        try:
            yield None
        finally:
            _held[key][1] -= 1
        return
    fd, stale = _acquire(path, exclusive=exclusive, folder=folder)
    if exclusive and record is not None:
        _write_record(fd, record)
    _held[key] = [fd, 1, exclusive, record]
    try:
        yield stale if exclusive else None
    finally:
        del _held[key]
        _release(path, fd, exclusive=exclusive)


def _lock_name(entry: str) -> str:
    return f"{LOCK_NAME}-" + "".join(c if c.isalnum() or c in "._-" else "_" for c in entry)


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike[str], *, entries: Sequence[str] | None = None,
                record: dict | None = None) -> Iterator[tuple[str | None, Callable[..., None]]]:
    """Lock ``folder`` for writing ``entries`` (``None``: the whole folder) for the block, after undoing
    what killed commands left half-done there (module docstring).

    A whole-folder claim holds ``.bemlearn-lock`` exclusively; a claim of entries holds it shared
    and one ``.bemlearn-lock-<entry>`` per entry exclusively, so two commands writing different
    files of one folder run side by side, and nothing runs beside a whole-folder claim.  A
    killed whole-folder claimer's snapshot is restored under an exclusive lock only.

    Yields:
        ``(incomplete, update)``: the description of a killed command whose half-written new
        folder this is (else ``None``), and ``update(**changes)``, which adds to this command's
        record in its lock files (e.g. the snapshot's name).

    Raises:
        OutputBusyError: another command holds a conflicting lock (the message names it).
    """
    folder = Path(folder)
    mine = {"pid": os.getpid(), "command": " ".join(["bemlearn", *sys.argv[1:]])[:500], "started": time.time(),
            **(record or {})}
    main_lock = folder / LOCK_NAME
    with contextlib.ExitStack() as stack:
        stale = stack.enter_context(_locked(main_lock, exclusive=entries is None, folder=folder, record=mine))
        incomplete = None
        if entries is None:   # nobody else writes here now: every record left is a killed command's
            incomplete = _recover(folder, stale, None)
            for leftover in sorted(folder.glob(f"{LOCK_NAME}-*")):
                with _locked(leftover, exclusive=True, folder=folder, record=None) as rec:
                    _recover(folder, rec, rec.get("entries") if rec else None)
        else:
            _recover_shared(folder, main_lock)
            for entry in sorted(set(entries)):
                rec = stack.enter_context(_locked(folder / _lock_name(entry), exclusive=True, folder=folder, record=mine))
                if rec and rec.get("entries") is not None:
                    _recover(folder, rec, [e for e in rec["entries"] if e in entries])

        def update(**changes) -> None:
            mine.update(changes)
            for held in _held.values():
                if held[3] is mine and held[2]:
                    _write_record(held[0], mine)

        yield incomplete, update


def _recover_shared(folder: Path, main_lock: Path) -> None:
    """Under a shared lock: restore a killed whole-folder claimer's snapshot if no other command uses the
    folder (the lock is upgraded to exclusive for it, and shared again after)."""
    held = _held.get(os.path.realpath(main_lock))
    if held is None or held[2] or fcntl is None:
        return
    fd = held[0]
    rec = _read_record(fd)
    if not rec or not rec.get("backup"):
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:   # other commands write entries here now: leave it to a whole-folder claim
        return
    try:
        rec = _read_record(fd)
        if rec and rec.get("backup"):
            _recover(folder, rec, None)
            os.ftruncate(fd, 0)
    finally:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)


def _entries(folder: Path, entries: Sequence[str] | None) -> list[str]:
    """The existing outputs among ``entries`` (``None``: everything in ``folder`` but bemlearn's own files)."""
    if entries is None:
        return sorted(c.name for c in folder.iterdir() if not c.name.startswith(INTERNAL_PREFIX))
    out = []
    for name in entries:
        p = folder / name
        if p.is_symlink() or p.is_file() or (p.is_dir() and any(not c.name.startswith(INTERNAL_PREFIX) for c in p.iterdir())):
            out.append(name)
    return out


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:  # another file system, or no hard links: a copy
        shutil.copy2(src, dst)


def _snapshot(folder: Path, names: Iterable[str], backup: Path) -> None:
    backup.mkdir()
    for name in names:
        src, dst = folder / name, backup / name
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            os.symlink(os.readlink(src), dst)
        elif src.is_dir():
            shutil.copytree(src, dst, symlinks=True, copy_function=_link_or_copy)
        else:
            _link_or_copy(str(src), str(dst))


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _restore(folder: Path, entries: Sequence[str] | None, backup: Path) -> None:
    """Put ``folder``'s outputs back as ``backup`` holds them: the current ones removed, the saved ones
    moved back (``entries``: those outputs only; ``None``: everything but bemlearn's own files)."""
    names = _entries(folder, None) if entries is None else list(entries)
    for name in names:
        _remove(folder / name)
    if backup.is_dir():
        saved = [p for p in sorted(backup.rglob("*"), key=lambda p: len(p.parts))
                 if entries is None or any(p.relative_to(backup).parts[:len(Path(e).parts)] == Path(e).parts for e in names)]
        for src in saved:
            rel = src.relative_to(backup)
            if (folder / rel).exists() or not (src.exists() or src.is_symlink()):
                continue
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(src, folder / rel)
        if not any(p.is_file() or p.is_symlink() for p in backup.rglob("*")):
            shutil.rmtree(backup, ignore_errors=True)


def _recover(folder: Path, rec: dict | None, entries: Sequence[str] | None) -> str | None:
    """Undo what the killed command of record ``rec`` left half-done in ``folder``: restore its snapshot
    of ``entries`` (``None``: the whole folder).  Returns the description of a killed command whose
    half-written new folder this is, else ``None``."""
    if not rec:
        return None
    backup = str(rec.get("backup") or "")
    if backup.startswith(BACKUP_PREFIX) and "/" not in backup and (folder / backup).is_dir():
        _restore(folder, entries, folder / backup)
        log.warning("%s: %s did not finish (killed?); its outputs were restored from the snapshot it had taken",
                    folder, _describe(rec))
        return None
    return _describe(rec) if rec.get("created") else None


def _rewritten(out: Path, name: str, backup: Path | None) -> bool:
    """Whether this command wrote ``out/name`` (it exists and is not the snapshotted original)."""
    path = out / name
    if not path.exists():
        return False
    old = backup / name if backup is not None else None
    if old is None or not old.exists():
        return True
    if os.path.samefile(path, old):
        return False
    import filecmp

    return not (path.is_file() and old.is_file() and filecmp.cmp(path, old, shallow=False))


@contextlib.contextmanager
def claim_outputs(
    folder: str | os.PathLike[str] | None,
    *,
    entries: Sequence[str] | None = None,
    default_name: str | None = None,
    root: str | os.PathLike[str] = "runs",
    force: bool = False,
    resume: bool = False,
    keep: Iterable[str] = (),
    keep_on_interrupt: Iterable[str] = (),
    what: str = "",
) -> Iterator[Path]:
    """Claim ``folder`` (or a new ``<root>/<default_name>-<timestamp>``) for a command's outputs (module docstring).

    Args:
        folder: the output folder, or ``None`` for a new default one (``default_name`` required).
        entries: names (relative paths) of what the command writes in the folder; ``None``: the
            whole folder is the output (a run folder).
        force: replace existing outputs.
        resume: continue in the existing outputs (``train --resume``); they are snapshotted like
            with ``force`` and restored if the command fails.
        keep: names of outputs worth keeping (e.g. ``data.npz``, ``checkpoint.pt``): once the command
            has written one, no later failure or interruption removes what it produced
            (:func:`worth_keeping`); the command should record the failure in its outputs.
        keep_on_interrupt: names that count only after Ctrl-C / SIGTERM (a complete, resumable state
            written on purpose when interrupted); ``keep`` names count there too.
        what: the command, for error messages.

    Yields:
        The claimed folder (it exists and is locked for the block).

    Raises:
        OutputBusyError: another command is writing the folder.
        OutputExistsError: outputs exist and neither ``force`` nor ``resume``.
        EnvironmentProblem: the folder cannot be created or written.
    """
    head = f"{what}: " if what else ""
    keep_any = tuple(keep)
    keep_interrupted = keep_any + tuple(keep_on_interrupt)
    if folder is None:
        if default_name is None:
            raise ArgumentError("claim_outputs: give a folder or a default_name")
        check_writable(root)
        first_new = first_new_folder(Path(root))
        out = new_run_dir(default_name, root=root, create=True)
        first_new = first_new or out
        created = True
    else:
        out = Path(folder)
        if out.exists() and not out.is_dir():
            raise EnvironmentProblem(f"{head}{out} is a file, expected a folder")
        check_writable(out)
        first_new = first_new_folder(out)
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.mkdir()
            created = True
        except FileExistsError:   # it existed, or another command created it meanwhile: it is locked below
            created, first_new = False, None
        except OSError as exc:
            raise (write_problem(out, exc) or exc) from None
    lock = folder_lock(out, entries=entries, record={"created": created, "entries": None if entries is None else list(entries)})
    incomplete, update = lock.__enter__()   # OutputBusyError: another command got the folder (even one we created): theirs
    try:
        existing = [] if created else _entries(out, entries)
        if existing and not (force or resume):
            shown = ", ".join(str(out / n) for n in existing[:8]) + (f" and {len(existing) - 8} more" if len(existing) > 8 else "")
            extra = f" (an incomplete run left by {incomplete})" if incomplete else ""
            raise OutputExistsError(f"{head}would overwrite {shown}{extra}; use --force to replace")
        backup = None
        if existing:
            backup = out / f"{BACKUP_PREFIX}{os.getpid()}-{time.monotonic_ns() % 10**9}"
            if backup.exists():
                shutil.rmtree(backup)
            try:
                _snapshot(out, existing, backup)
            except OSError as exc:
                shutil.rmtree(backup, ignore_errors=True)
                raise (write_problem(backup, exc) or exc) from None
            update(backup=backup.name)
        try:
            yield out
        except BaseException as exc:
            names = keep_interrupted if isinstance(exc, KeyboardInterrupt) else keep_any
            if worth_keeping(out, names, backup):
                if not resume:
                    _drop_stale(out, entries, backup)
                _discard(backup)
                if not isinstance(exc, KeyboardInterrupt):
                    log.warning("%s%s: kept after the failure, with what the command produced (%s)", head, out,
                                ", ".join(_entries(out, entries)))
            else:
                _undo(out, created, first_new, entries, backup)
            raise
        _discard(backup)
    finally:
        lock.__exit__(None, None, None)


def worth_keeping(out: Path, names: Iterable[str], backup: Path | None = None) -> bool:
    """Whether a command that failed in ``out`` produced something worth keeping: it wrote (new, or
    replaced by a different file) one of ``names``.  The one rule of what a failure removes: a folder
    is removed, or put back as it was, only when this is false (module docstring)."""
    return any(_rewritten(out, name, backup) for name in names)


def _drop_stale(out: Path, entries: Sequence[str] | None, backup: Path | None) -> None:
    """Remove the replaced run's outputs that the failed command had not rewritten, so that the kept new
    files never sit beside an old run's (a new checkpoint beside an old report)."""
    if backup is None:
        return
    for name in _entries(out, entries):
        if (backup / name).exists() and not _rewritten(out, name, backup):
            _remove(out / name)


def _discard(backup: Path | None) -> None:
    if backup is not None:
        shutil.rmtree(backup, ignore_errors=True)


def _prune_empty_parents(out: Path, name: str) -> None:
    """Remove the folders between ``out`` and the entry ``name`` (e.g. ``tb`` of ``tb/simulate``) left empty."""
    parent = (out / name).parent
    while parent != out and out in parent.parents:
        try:
            parent.rmdir()   # only when empty
        except OSError:
            return
        parent = parent.parent


def _undo(out: Path, created: bool, first_new: Path | None, entries: Sequence[str] | None, backup: Path | None) -> None:
    """A failed command: remove the folder it created, or put its outputs back as they were."""
    if created:
        if entries is None:
            for name in _entries(out, None):
                _remove(out / name)
        else:
            for name in entries:
                _remove(out / name)
                _prune_empty_parents(out, name)
        if first_new is not None and not any(_entries(out, None)):
            shutil.rmtree(first_new, ignore_errors=True)
            log.info("removed %s after the failure", first_new)
        return
    if backup is not None:
        _restore(out, entries, backup)
    else:
        for name in _entries(out, None) if entries is None else entries:
            _remove(out / name)
    log.info("%s: restored the outputs as they were before the failed command", out)
