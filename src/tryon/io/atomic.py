"""Atomic outputs: write under a temporary sibling name, rename into place on success.

A failed or interrupted run therefore never leaves a half-written file (or folder)
that looks complete: either the old content is still there, or the new one is.
``os.replace`` is atomic when source and destination are on the same file system,
which is why the temporary name is always created in the destination's directory.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from tryon.errors import InputFileError

__all__ = ["atomic_write", "atomic_path", "atomic_output_dir"]


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


@contextmanager
def atomic_output_dir(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Build a folder under a temporary sibling name, then rename it to ``path``.

    Yields the temporary folder: write everything into it. On success an existing
    ``path`` is replaced (it is first moved aside, so there is never a moment with a
    half-filled ``path``); on an exception the temporary folder is removed and an
    existing ``path`` is left untouched.
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise InputFileError(f"output folder {target} exists and is a file; remove it or choose another name")
    parent = target.parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmpdir", dir=parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0o700; give what mkdir would
    _swap_into_place(tmp, target)


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
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
