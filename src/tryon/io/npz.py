"""Checked reading of ``.npz`` inputs (motions, observations, frames, checkpoints).

`read_npz` refuses oversized files and arrays before decompressing them (the array
headers give shape and dtype), never unpickles, and turns every failure into an
`InputFileError`; `float_array`, `int_array`, `scalar` and `text` check one entry's
dtype, shape and finiteness with a message naming the file and key.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from tryon.errors import InputFileError
from tryon.limits import LIMITS, check_file_size, check_limit

Shape = tuple[int | None, ...]


def read_npz(path: str | Path, what: str, allow_large: bool | None = None,
             keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """All arrays of the npz at `path` (`what` names the file kind in messages), or only
    those named in `keys` (the others are not decompressed; a missing one is an error)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{what} {path} does not exist; check the path")
    check_file_size(path, what, allow_large)
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                _check_member(archive, info, path, what, allow_large)
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in keys or () if k not in data.files]
            if missing:
                raise InputFileError(f"{what} {path} has no {', '.join(map(repr, missing))}")
            return {key: data[key] for key in (data.files if keys is None else keys)}
    except InputFileError:
        raise
    # zipfile signals an unsupported compression method with NotImplementedError
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, RuntimeError, NotImplementedError) as exc:
        raise InputFileError(f"{what} {path}: not a readable .npz archive ({exc})") from None


def _check_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path: Path, what: str,
                  allow_large: bool | None) -> None:
    check_limit(f"{what} {path}: member {info.filename!r} (bytes)", info.file_size, LIMITS.max_array_bytes,
                "max_array_bytes", allow_large)
    if not info.filename.endswith(".npy"):
        return
    with archive.open(info) as fh:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
        else:
            shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
    key = info.filename[:-4]
    if dtype.hasobject:
        raise InputFileError(f"{what} {path}: array {key!r} holds Python objects; only numeric and text arrays are read")
    nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
    check_limit(f"{what} {path}: array {key!r} (bytes)", nbytes, LIMITS.max_array_bytes, "max_array_bytes", allow_large)


def _shape_ok(shape: tuple[int, ...], expected: Shape) -> bool:
    return len(shape) == len(expected) and all(e is None or s == e for s, e in zip(shape, expected))


def _shape_text(expected: Shape) -> str:
    return "[" + ", ".join("*" if e is None else str(e) for e in expected) + "]"


def float_array(arrays: dict[str, np.ndarray], key: str, source: str, shape: Shape) -> np.ndarray:
    """Entry `key` as finite float64 of `shape` (None: any length)."""
    a = _get(arrays, key, source)
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise InputFileError(f"{source}: {key!r} must hold numbers, got dtype {a.dtype}")
    if not _shape_ok(a.shape, shape):
        raise InputFileError(f"{source}: {key!r} must be {_shape_text(shape)} numbers, got shape {list(a.shape)}")
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise InputFileError(f"{source}: {key!r} contains NaN or infinite values")
    return a


def int_array(arrays: dict[str, np.ndarray], key: str, source: str, shape: Shape | None,
              below: int | None = None) -> np.ndarray:
    """Entry `key` as int64 of `shape` (None: any), every value in [0, below)."""
    a = _get(arrays, key, source)
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise InputFileError(f"{source}: {key!r} must hold integer indices, got dtype {a.dtype}")
    if shape is not None and not _shape_ok(a.shape, shape):
        raise InputFileError(f"{source}: {key!r} must be {_shape_text(shape)} integer indices, got shape {list(a.shape)}")
    a = a.astype(np.int64)
    if below is not None and a.size and (a.min() < 0 or a.max() >= below):
        raise InputFileError(f"{source}: {key!r} indices must lie in [0, {below - 1}], got [{a.min()}, {a.max()}]")
    return a


def scalar(arrays: dict[str, np.ndarray], key: str, source: str, low: float = -np.inf, high: float = np.inf,
           unit: str = "") -> float:
    """Entry `key` as one finite number in [low, high]."""
    a = _get(arrays, key, source)
    if a.size != 1 or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise InputFileError(f"{source}: {key!r} must be one number, got dtype {a.dtype} shape {list(a.shape)}")
    value = float(a.reshape(()))
    unit_txt = f" {unit}" if unit else ""
    if not np.isfinite(value) or not low <= value <= high:
        raise InputFileError(f"{source}: {key!r} must lie in [{low:g}, {high:g}]{unit_txt}, got {value:g}")
    return value


def text(arrays: dict[str, np.ndarray], key: str, source: str, default: str = "", max_length: int = 1000) -> str:
    if key not in arrays:
        return default
    a = arrays[key]
    if a.size != 1 or a.dtype.kind not in "US":
        raise InputFileError(f"{source}: {key!r} must be one text value, got dtype {a.dtype} shape {list(a.shape)}")
    value = a.reshape(()).item()
    value = value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)
    return value[:max_length]


def text_list(arrays: dict[str, np.ndarray], key: str, source: str, max_length: int = 200) -> list[str]:
    a = _get(arrays, key, source)
    if a.ndim != 1 or (a.size and a.dtype.kind not in "US"):
        raise InputFileError(f"{source}: {key!r} must be a list of text, got dtype {a.dtype} shape {list(a.shape)}")
    return [(v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v))[:max_length] for v in a.tolist()]


def _get(arrays: dict[str, Any], key: str, source: str) -> np.ndarray:
    if key not in arrays:
        raise InputFileError(f"{source}: missing the array {key!r} (it has {sorted(arrays)})")
    return np.asarray(arrays[key])
