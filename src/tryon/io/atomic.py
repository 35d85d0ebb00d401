"""Atomic outputs: write under a temporary sibling name, rename into place on success.

A failed or interrupted run therefore never leaves a half-written file (or folder)
that looks complete: either the old content is still there, or the new one is.
``os.replace`` is atomic when source and destination are on the same file system,
which is why the temporary name is always created in the destination's directory.

Output folders are owned: every folder tryon writes carries the marker file
``OWNER_MARKER``, and a run only ever replaces a folder that carries it (or is empty).
Any other existing folder is refused with a message, unless the caller passes
``force=True`` (the CLI's ``--force``); even then the file-system root, the home folder,
the working directory and its parents are never replaced.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from tryon.errors import InputFileError, OutputFolderError

__all__ = ["atomic_write", "atomic_path", "atomic_output_dir", "check_output_dir", "claim_work_dir", "publish_dir",
           "is_being_written",
           "OWNER_MARKER"]

OWNER_MARKER = ".tryon-output.json"


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def _default_file_mode() -> int:
    """Permission bits a plain ``open(path, "w")`` would give (0o666 minus the umask)."""
    return 0o666 & ~_umask()


def _prepare_parent(path: Path) -> Path:
    parent = path.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputFileError(
            f"cannot create the folder {parent} for output {path}: {exc}; choose a writable location"
        ) from exc
    if path.is_dir():
        raise InputFileError(f"output {path} is an existing folder; give a file name instead")
    return parent


def _remove_quietly(path: str | Path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary file name next to ``path``; rename it onto ``path`` on success.

    For libraries that insist on writing to a file name themselves (ffmpeg, ...). The
    temporary name keeps the suffix of ``path`` so format detection from the extension
    still works. On an exception the temporary file is deleted and ``path`` is untouched.
    """
    target = Path(path)
    parent = _prepare_parent(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{target.suffix}", dir=parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, _default_file_mode())
        os.replace(tmp, target)
    except BaseException:
        _remove_quietly(tmp)
        raise


@contextmanager
def atomic_write(
    path: str | os.PathLike[str], mode: str = "w", encoding: str | None = "utf-8", newline: str | None = None
) -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path`` for writing; move it onto ``path`` on success.

    ``mode`` is ``"w"`` (text) or ``"wb"`` (binary). If the ``with`` body raises, the
    temporary file is deleted and any previous content of ``path`` is left as it was.
    """
    if mode not in ("w", "wb"):
        raise InputFileError(f"atomic_write mode must be 'w' or 'wb', got {mode!r}")
    target = Path(path)
    parent = _prepare_parent(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=parent)
    try:
        if mode == "wb":
            handle = os.fdopen(fd, "wb")
        else:
            handle = os.fdopen(fd, "w", encoding=encoding, newline=newline)
        with handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, _default_file_mode())
        os.replace(tmp, target)
    except BaseException:
        _remove_quietly(tmp)
        raise


def _protected(path: Path) -> str | None:
    """Why `path` may never be replaced, or None."""
    resolved = path.resolve()
    if resolved == Path(resolved.anchor):
        return "it is the root of the file system"
    if resolved.parent == Path(resolved.anchor):
        return "it is a top-level folder of the file system"
    home = Path.home().resolve()
    if resolved == home:
        return "it is your home folder"
    if resolved in home.parents:
        return "it contains your home folder"
    cwd = Path.cwd().resolve()
    if resolved == cwd:
        return "it is the working directory"
    if resolved in cwd.parents:
        return "it contains the working directory"
    return None


def _writable_ancestor(path: Path) -> None:
    """Fail now (not after the run) when `path` cannot be created."""
    probe = path.resolve().parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise OutputFolderError(f"output {path}: {probe} is a file, so the folder cannot be created there")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputFolderError(f"output {path}: no permission to write in {probe}; choose another --out")


def is_owned(path: str | os.PathLike[str]) -> bool:
    """True when `path` is a folder written by tryon: it holds the owner marker as a plain
    file (not a link) that says so."""
    marker = Path(path) / OWNER_MARKER
    try:
        if marker.is_symlink() or not marker.is_file():
            return False
        return json.loads(marker.read_text()).get("written_by") == "tryon"
    except (OSError, ValueError, AttributeError):
        return False


def _normalised(path: str | os.PathLike[str]) -> Path:
    """The output path with `.` and `..` folded away (so that what is checked before the run
    is what the run writes), refusing names that end in `..`."""
    text = os.fspath(path)
    if text.strip() == "":
        raise OutputFolderError("the output folder name is empty; give --out DIR")
    return Path(os.path.normpath(text))


def check_output_dir(path: str | os.PathLike[str], force: bool = False) -> Path:
    """Check, before any work, that `path` may become an output folder: it does not exist,
    is empty, or was written by tryon (``force`` allows any other folder, never a
    protected one). Returns the normalised path; raises `OutputFolderError` naming the
    problem and the way out."""
    target = _normalised(path)
    why = _protected(target)
    if why is not None or target.name in ("", ".", ".."):
        why = why or "it names no folder of its own"
        raise OutputFolderError(f"refusing to use {path} as an output folder: {why}; give a new folder, e.g. out/run")
    if target.is_symlink():
        raise OutputFolderError(f"output folder {path} is a symbolic link; give a real folder name")
    if target.exists():
        if not target.is_dir():
            raise OutputFolderError(f"output folder {path} exists and is a file; remove it or choose another name")
        try:
            foreign = not is_owned(target) and any(target.iterdir())
        except OSError as exc:
            raise OutputFolderError(f"output folder {path} cannot be read ({exc.strerror}); choose another --out") from exc
        if foreign and not force:
            raise OutputFolderError(
                f"output folder {path} exists and was not written by tryon (no {OWNER_MARKER}); it would be "
                f"replaced: choose a new folder, empty it, or pass --force to replace it")
    _writable_ancestor(target)
    return target


def _write_marker(folder: Path) -> None:
    from tryon import __version__

    info = {"written_by": "tryon", "version": __version__, "command": " ".join(sys.argv[:1] + sys.argv[1:2]),
            "time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    (folder / OWNER_MARKER).write_text(json.dumps(info) + "\n")


def claim_work_dir(path: str | os.PathLike[str], resume: bool = False, force: bool = False) -> Path:
    """Create (or, with `resume`, reopen) a run's working folder such as ``OUT.partial``.
    An owned folder left by an earlier run is cleared unless resuming; a foreign one is
    refused like an output folder."""
    work = check_output_dir(path, force=force)
    if work.exists() and not resume:
        _lock(work)  # refuses while another run writes there
        _unlock(work)
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=resume)
    if not is_owned(work):
        _write_marker(work)
    _lock(work)
    return work


_LOCKS: dict[str, int] = {}


def _lock(work: Path) -> None:
    """Hold an exclusive lock on `work` for the rest of this run (released by
    `publish_dir` or when the process ends): two runs never share a working folder."""
    key = str(work.resolve())
    if key in _LOCKS:
        return
    fd = os.open(work / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        raise OutputFolderError(f"another tryon run is writing {work}; wait for it or choose another --out") from exc
    _LOCKS[key] = fd


def is_being_written(folder: str | os.PathLike[str]) -> bool:
    """True while another process holds `folder`'s run lock (a generator writing it)."""
    lock = Path(folder) / ".lock"
    if str(Path(folder).resolve()) in _LOCKS or not lock.is_file():
        return False  # this process's own run, or no run at all
    try:
        fd = os.open(lock, os.O_RDONLY)
    except OSError as exc:
        raise OutputFolderError(f"cannot read {lock} to see whether a run is writing {folder} ({exc.strerror})") from exc
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)   # shared: conflicts with a run's exclusive lock only
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # closing releases a lock this call took
    return False


def _unlock(work: Path) -> None:
    fd = _LOCKS.pop(str(work.resolve()), None)
    if fd is not None:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def publish_dir(work: str | os.PathLike[str], target: str | os.PathLike[str], force: bool = False) -> Path:
    """Rename the finished folder `work` to `target` (replacing an owned `target`)."""
    work, target = Path(work), check_output_dir(target, force=force)
    if not is_owned(work):
        _write_marker(work)
    _unlock(work)
    (work / ".lock").unlink(missing_ok=True)
    os.chmod(work, 0o777 & ~_umask())
    _swap_into_place(work, target)
    return target


@contextmanager
def atomic_output_dir(path: str | os.PathLike[str], force: bool = False) -> Iterator[Path]:
    """Build a folder under a temporary sibling name, then rename it to ``path``.

    Yields the temporary folder: write everything into it. On success an existing
    ``path`` (empty or written by tryon, see `check_output_dir`) is replaced; it is first
    moved aside, so there is never a moment with a half-filled ``path``. On an exception
    the temporary folder is removed and an existing ``path`` is left untouched.
    """
    target = check_output_dir(path, force=force)
    parent = target.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFolderError(f"cannot create the folder {parent} for output {path}: {exc.strerror}") from exc
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmpdir", dir=parent))
    try:
        _write_marker(tmp)
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    try:
        publish_dir(tmp, target, force=force)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _swap_into_place(tmp: Path, target: Path) -> None:
    """Rename ``tmp`` to ``target``, moving an existing ``target`` aside first."""
    old: Path | None = None
    if target.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
        os.rmdir(old)
        os.replace(target, old)
    try:
        os.replace(tmp, target)
    except BaseException:
        if old is not None:
            os.replace(old, target)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
