"""Animation frames: compressed ``.npz`` sequences and numbered OBJ sequences."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from tryon.errors import InputFileError, MeshError
from tryon.io.atomic import atomic_write
from tryon.io.mesh_io import _as_numpy, _checked_mesh, _checked_uv, write_obj

__all__ = ["save_frames_npz", "load_frames_npz", "write_obj_sequence"]

PathLike = str | os.PathLike[str]

def _checked_positions(positions: Any, out: Path) -> np.ndarray:
    p = _as_numpy(positions, np.float64)
    if p.ndim != 3 or p.shape[2] != 3 or p.shape[0] == 0:
        raise MeshError(f"writing {out}: positions must be [T, N, 3] with T >= 1, got shape {tuple(p.shape)}")
    if not np.isfinite(p).all():
        bad = int(np.argmin(np.isfinite(p).reshape(len(p), -1).all(axis=1)))
        raise MeshError(f"writing {out}: frame {bad} contains NaN or inf; check the simulation output")
    return p


def save_frames_npz(
    path: PathLike, positions: Any, faces: Any, uv: Any = None, times: Any = None, **extra: Any
) -> Path:
    """Save a sequence ``positions [T,N,3]`` with its ``faces [F,3]`` as a compressed npz (atomic).

    Optional ``uv [N,2]``, ``times [T]`` (seconds) and any further named arrays
    (``extra``) are stored alongside; :func:`load_frames_npz` returns them all.
    """
    out = Path(path)
    p = _checked_positions(positions, out)
    _, f = _checked_mesh(p[0], faces, out)
    arrays: dict[str, np.ndarray] = {"positions": p, "faces": f}
    if uv is not None:
        arrays["uv"] = _checked_uv(uv, p.shape[1], out)
    if times is not None:
        t = _as_numpy(times, np.float64).reshape(-1)
        if t.shape != (len(p),):
            raise MeshError(f"writing {out}: times must have one entry per frame ({len(p)}), got {t.size}")
        arrays["times"] = t
    for key, value in extra.items():
        arr = _as_numpy(value)
        if arr.dtype == object:
            raise MeshError(f"writing {out}: extra array {key!r} is not numeric; pass a numpy array")
        arrays[key] = arr
    with atomic_write(out, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return out


def load_frames_npz(path: PathLike) -> dict[str, np.ndarray]:
    """Load a file written by :func:`save_frames_npz` into a dict of arrays.

    Always has ``positions [T,N,3]`` and ``faces [F,3]``; ``uv``, ``times`` and extras
    when they were saved.
    """
    from tryon.io.npz import read_npz

    src = Path(path)
    arrays = read_npz(src, "frames file")
    missing = [k for k in ("positions", "faces") if k not in arrays]
    if missing:
        raise InputFileError(f"frames file {src} lacks {missing}; it was not written by save_frames_npz")
    p, f = arrays["positions"], arrays["faces"]
    if p.ndim != 3 or p.shape[2] != 3 or p.dtype.kind not in "fiu":
        raise InputFileError(f"frames file {src}: positions must be numbers [T, N, 3], got {p.dtype} {p.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and f.dtype.kind not in "iu"):
        raise InputFileError(f"frames file {src}: faces must be integer indices [F, 3], got {f.dtype} {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= p.shape[1]):
        raise InputFileError(f"frames file {src}: face indices must lie in [0, {p.shape[1] - 1}]")
    return arrays


def write_obj_sequence(
    directory: PathLike, positions: Any, faces: Any, uv: Any = None, prefix: str = "frame_"
) -> list[Path]:
    """Write one OBJ per frame: ``prefix0000.obj``, ``prefix0001.obj``, ... (each file atomic).

    Numbers are zero-padded to at least 4 digits (more when there are more frames), so
    the files sort in frame order. Returns the written paths.
    """
    folder = Path(directory)
    p = _checked_positions(positions, folder)
    _, f = _checked_mesh(p[0], faces, folder)
    uv_arr = None if uv is None else _checked_uv(uv, p.shape[1], folder)
    digits = max(4, len(str(len(p) - 1)))
    folder.mkdir(parents=True, exist_ok=True)
    return [write_obj(folder / f"{prefix}{i:0{digits}d}.obj", frame, f, uv_arr) for i, frame in enumerate(p)]
