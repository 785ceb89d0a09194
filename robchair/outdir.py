"""Output folders that never destroy data: build the outputs beside the target, then move them in.

The rules (shared by every command that writes a folder: ``sim``, ``run``, ``map``, ``pid`` and
``bench table52``):

* A missing ``--out`` folder is created, with any missing parents; an existing *empty* folder is used
  as if it were new.
* A folder this project wrote holds the marker file ``.robchair-output`` (JSON listing the entries
  written). Writing there again needs ``overwrite=True`` (``--overwrite``): the entries of the earlier
  output are then replaced; files added to the folder since are kept.
* The current directory (or one of its parents) and any other non-empty folder are refused unless
  ``overwrite=True``; even then only entries with the same names as the new outputs are replaced, and
  nothing else in the folder is touched.
* Outputs are built in a hidden staging folder and moved in only when the command succeeds. A failed
  command, or one stopped by a signal (also while it creates the parents), leaves no new folder
  behind: the staging folder and every parent it created for it are removed (only those, and only
  while empty).
* One command at a time per target: the first check takes an exclusive lock (``flock``) on the file
  ``.<name>.lock`` beside it, held until the output is in place (or the process ends); a second
  command refuses at once, with or without ``--overwrite``.
* A staging folder is named ``.<name>.partial-<pid>-<hex>``. One left by a process that was killed
  (SIGKILL, power loss) is removed by the next command writing the same target, which says so on
  stderr; one whose pid is still alive is left alone.
"""

from __future__ import annotations

import atexit
import contextlib
import contextvars
import errno
import fcntl
import json
import logging
import os
import re
import secrets
import shutil
from collections.abc import Iterator
from pathlib import Path

from robchair.platform.errors import RobChairError

MARKER = ".robchair-output"
log = logging.getLogger(__name__)
#: targets this process holds the lock of -> the open lock file's descriptor
_LOCKS: dict[Path, int] = {}

#: Default of ``overwrite`` where a command cannot pass it down (set by the CLI around the command).
OVERWRITE: contextvars.ContextVar[bool] = contextvars.ContextVar("robchair_overwrite", default=False)


class OutputDirError(RobChairError, FileExistsError):
    """The output folder cannot be written without destroying data (the message says what to do)."""


def _marker_entries(folder: Path) -> list[str] | None:
    """Entries listed by the folder's marker; None if the folder holds no readable marker."""
    try:
        data = json.loads((folder / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    entries = data.get("entries") if isinstance(data, dict) else None
    if not isinstance(entries, list):
        return None
    # Plain names only: a marker must never make us touch anything outside its own folder.
    return [e for e in entries if isinstance(e, str) and e not in ("", ".", "..") and "/" not in e]


class OutputDir:
    """One command's output folder: checked when created, written by :meth:`stage`.

    Args:
        target: The folder to write (``--out``).
        overwrite: Allow writing into an existing non-empty folder (``--overwrite``); None takes the
            value of :data:`OVERWRITE`.

    Raises:
        OutputDirError: ``target`` is a file, the current directory or one of its parents, or a
            non-empty folder, and ``overwrite`` is false.
    """

    def __init__(self, target: Path | str, *, overwrite: bool | None = None) -> None:
        self.given = Path(target)
        self.target = self.given.resolve()
        self.overwrite = OVERWRITE.get() if overwrite is None else bool(overwrite)
        self.check()

    def check(self) -> None:
        """Refuse a target that would lose data, or that another command is writing (the lock is
        taken here when the target's parent exists)."""
        t, name = self.target, str(self.given)
        if t.parent.is_dir():
            _lock(t, name)
        if t.exists() and not t.is_dir():
            raise OutputDirError(f"--out {name}: is a file, not a folder; choose a folder name")
        if self.overwrite or not t.exists():
            return
        if Path.cwd().resolve().is_relative_to(t):
            raise OutputDirError(
                f"--out {name}: is the current folder (or holds it); choose a new folder, or pass "
                "--overwrite to write into it (other files are kept)"
            )
        if not any(t.iterdir()):
            return
        if _marker_entries(t) is not None:
            raise OutputDirError(
                f"--out {name}: holds an earlier robchair output; choose a new folder, or pass "
                "--overwrite to replace that output (files added to it are kept)"
            )
        raise OutputDirError(
            f"--out {name}: folder is not empty and was not written by robchair; choose a new folder, "
            "or pass --overwrite to write into it (other files are kept)"
        )

    @contextlib.contextmanager
    def stage(self) -> Iterator[Path]:
        """Yield an empty staging folder whose entries become the output if the block succeeds.

        On any exception the staging folder and the parents created for it are removed, and an
        existing target is left as it was.
        """
        t = self.target
        created: list[Path] = []
        try:
            for parent in reversed([p for p in t.parents if not p.exists()]):
                with _stop_signals_held():  # a stop signal cannot fall between the mkdir and the record
                    try:
                        parent.mkdir()
                    except FileExistsError:  # created by someone else meanwhile: not ours to remove
                        continue
                    created.append(parent)
            self.check()
        except BaseException:
            _unlock(t)
            _remove_created(created)
            raise
        try:
            _remove_stale_staging(t)
            # Into an existing folder entry by entry; a new (or empty, unused) one is swapped in whole.
            merge = t.exists() and (any(t.iterdir()) or Path.cwd().resolve().is_relative_to(t))
            staging = _new_hidden_dir(t if merge else t.parent, f".{t.name}.partial-{os.getpid()}-")
            try:
                yield staging
                if merge:
                    self._merge(staging)
                else:
                    _write_marker(staging, sorted(p.name for p in staging.iterdir()))
                    staging.rename(t)  # rename(2) also replaces an empty folder
            finally:
                shutil.rmtree(staging, ignore_errors=True)
        except OSError as exc:
            _unlock(t)
            _remove_created(created)
            if exc.errno in (errno.ENOSPC, errno.EDQUOT) and exc.filename is None:
                raise OSError(exc.errno, f"{exc.strerror} while writing --out", str(self.given)) from exc
            raise
        except BaseException:
            _unlock(t)
            _remove_created(created)
            raise
        _unlock(t)

    def _merge(self, staging: Path) -> None:
        """Move the staged entries into the non-empty target, replacing same-named entries and the
        entries of an earlier output of ours; everything else in the target is left alone."""
        t = self.target
        new = sorted(p.name for p in staging.iterdir())
        old = _marker_entries(t) or []
        replace = [n for n in dict.fromkeys([*new, *old, MARKER]) if os.path.lexists(t / n)]
        trash = _new_hidden_dir(t, f".{t.name}.old-")
        moved_out: list[str] = []
        moved_in: list[str] = []
        try:
            for n in replace:
                (t / n).rename(trash / n)
                moved_out.append(n)
            for n in new:
                (staging / n).rename(t / n)
                moved_in.append(n)
            _write_marker(t, new)
        except BaseException:
            for n in moved_in:  # undo: put the previous entries back
                with contextlib.suppress(OSError):
                    (t / n).rename(staging / n)
            for n in moved_out:
                with contextlib.suppress(OSError):
                    (trash / n).rename(t / n)
            with contextlib.suppress(OSError):
                trash.rmdir()  # only if everything went back
            raise
        shutil.rmtree(trash, ignore_errors=True)


def _lock_path(target: Path) -> Path:
    return target.parent / f".{target.name}.lock"


def _lock(target: Path, name: str) -> None:
    """Hold the exclusive lock of ``target`` (once per process); refuse if another process holds it."""
    if target in _LOCKS:
        return
    path = _lock_path(target)
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise OutputDirError(
                f"--out {name}: another robchair command (pid {owner}) is writing it; wait for it to "
                "finish or choose another folder"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino  # not unlinked by its last holder meanwhile
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    _LOCKS[target] = fd


def _unlock(target: Path) -> None:
    fd = _LOCKS.pop(target, None)
    if fd is None:
        return
    with contextlib.suppress(OSError):
        os.unlink(_lock_path(target))  # while still holding it: a waiting process then retries
    os.close(fd)


@atexit.register
def _unlock_all() -> None:
    for target in list(_LOCKS):
        _unlock(target)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_stale_staging(target: Path) -> None:
    """Remove the staging folders of ``target`` no live process owns (called with its lock held)."""
    pattern = re.compile(rf"\.{re.escape(target.name)}\.partial-(?:(\d+)-)?[0-9a-f]+")
    for folder in (target.parent, target):
        if not folder.is_dir():
            continue
        for p in folder.iterdir():
            m = pattern.fullmatch(p.name)
            if m is None or not p.is_dir():
                continue
            pid = int(m.group(1)) if m.group(1) else None
            if pid is not None and pid != os.getpid() and _pid_alive(pid):
                continue
            shutil.rmtree(p, ignore_errors=True)
            log.warning("removed %s: the staging folder of an interrupted robchair command", p)


@contextlib.contextmanager
def _stop_signals_held() -> Iterator[None]:
    """Hold SIGINT, SIGTERM and SIGHUP back for the block (this thread); one that came meanwhile is
    delivered, and its handler runs, right after."""
    import signal

    held = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _remove_created(created: list[Path]) -> None:
    for parent in reversed(created):
        with contextlib.suppress(OSError):
            parent.rmdir()


def _new_hidden_dir(parent: Path, prefix: str) -> Path:
    """A new uniquely named folder in ``parent`` with the usual permissions (the umask's, unlike
    ``tempfile.mkdtemp``'s owner-only ones, which the finished output would keep)."""
    for _ in range(100):
        path = parent / f"{prefix}{secrets.token_hex(4)}"
        try:
            path.mkdir()
        except FileExistsError:
            continue
        return path
    raise FileExistsError(f"cannot create a staging folder in {parent}")


def _write_marker(folder: Path, entries: list[str]) -> None:
    tmp = folder / f"{MARKER}.tmp"
    tmp.write_text(json.dumps({"written_by": "robchair", "entries": entries}) + "\n", encoding="utf-8")
    tmp.replace(folder / MARKER)


def check_output_dir(target: Path | str, *, overwrite: bool | None = None) -> OutputDir:
    """Check ``target`` now (before any work) and return the folder to :meth:`OutputDir.stage` later.

    Raises:
        OutputDirError: See :class:`OutputDir`.
    """
    return OutputDir(target, overwrite=overwrite)


@contextlib.contextmanager
def staged_output_dir(target: Path | str, *, overwrite: bool | None = None) -> Iterator[Path]:
    """Yield a fresh staging folder whose contents become ``target`` only if the block finishes.

    Args:
        target: The output folder (see the module docstring for what may be written where).
        overwrite: ``--overwrite``; None takes :data:`OVERWRITE`.

    Raises:
        OutputDirError: ``target`` may not be written (checked before the block runs).
    """
    with OutputDir(target, overwrite=overwrite).stage() as staging:
        yield staging


@contextlib.contextmanager
def overwrite_allowed(allowed: bool) -> Iterator[None]:
    """Set :data:`OVERWRITE` for the commands run inside the block."""
    token = OVERWRITE.set(bool(allowed))
    try:
        yield
    finally:
        OVERWRITE.reset(token)


@contextlib.contextmanager
def deferred_stdout() -> Iterator[None]:
    """Hold what the block prints on stdout and print it only if the block succeeds.

    A failing command then shows its one-line error alone, not a table header or half a report
    before it.
    """
    import io
    import sys

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        yield
    sys.stdout.write(buffer.getvalue())
    sys.stdout.flush()


#: ``--overwrite``'s help, the same on every command that writes a folder.
OVERWRITE_HELP = (
    "write into an existing non-empty --out folder (same-named entries and an earlier robchair output "
    "there are replaced; other files are kept)"
)


def timestamped_dir(name: str, root: Path | str = "runs") -> Path:
    """A new folder name for a command run without ``--out``: ``<root>/<name>-<UTC time>``.

    The time is ``YYYYMMDDTHHMMSSZ``; when that folder exists already (two runs within one second),
    ``-2``, ``-3``, ... is appended, so running a command twice never meets its earlier output.

    Args:
        name: what wrote the folder (a command or scenario name).
        root: the parent folder, relative to the current directory (default ``runs``).
    """
    from datetime import UTC, datetime

    base = Path(root) / f"{name}-{datetime.now(UTC).strftime('%Y%m%dT%H%M%SZ')}"
    path, k = base, 1
    while os.path.lexists(path):
        k += 1
        path = base.with_name(f"{base.name}-{k}")
    return path


def check_own_file(folder: Path | str, name: str, *, overwrite: bool = False) -> None:
    """Refuse to replace ``folder/name`` unless robchair wrote it or ``overwrite`` is set.

    A file is robchair's when the folder's marker lists it (see :func:`add_marker_entry`). Used by the
    commands that add one file to an existing run folder (``report``, ``view``).

    Raises:
        OutputDirError: the file exists, the marker does not list it and ``overwrite`` is false.
    """
    path = Path(folder) / name
    if overwrite or not os.path.lexists(path) or name in (_marker_entries(Path(folder)) or []):
        return
    raise OutputDirError(
        f"{path}: exists and was not written by robchair; move it away, or pass --overwrite to replace it"
    )


def add_marker_entry(folder: Path | str, name: str) -> None:
    """List ``name`` in the folder's marker (creating the marker), so a later run may replace it."""
    folder = Path(folder)
    entries = _marker_entries(folder) or []
    if name not in entries:
        _write_marker(folder, sorted([*entries, name]))
