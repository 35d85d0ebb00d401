"""Safety limits checked before any work starts: a small input file must not start hours
of stepping, millions of frames or a multi-gigabyte allocation by accident.

Every limit raises `LimitError` naming the limit, the value asked for and how to lift it.
Limits marked overridable are lifted by `allow_large=True` (Python API), the environment
variable ``TRYON_ALLOW_LARGE=1`` or the CLI flag ``--allow-large``; the others guard against
malformed or hostile files (YAML alias bombs) and always apply.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from tryon.errors import LimitError

ALLOW_LARGE_ENV = "TRYON_ALLOW_LARGE"
GIB = 1 << 30
MIB = 1 << 20


@dataclass(frozen=True)
class Limits:
    max_steps: int = 200_000  # simulation steps of one run
    max_frames: int = 20_000  # written or skinned frames of one run or motion
    max_vertices: int = 200_000  # cloth vertices (a grid of about 447 x 447)
    max_obstacle_vertices: int = 2_000_000  # all obstacle meshes together
    max_grid_resolution: int = 2_000  # vertices along one side of a grid cloth
    max_memory_bytes: int = 16 * GIB  # estimated memory of a run before it starts
    max_file_bytes: int = 200 * MIB  # any input file (OBJ, BVH, npz, YAML)
    max_array_bytes: int = 2 * GIB  # one decompressed array of an npz input
    max_joints: int = 1_000  # BVH skeleton joints
    max_yaml_bytes: int = 1 * MIB  # scene YAML text (not overridable)
    max_yaml_aliases: int = 100  # YAML alias references (*name) in one document (not overridable)
    max_yaml_nodes: int = 100_000  # YAML nodes in one document (not overridable)


LIMITS = Limits()


def large_allowed(allow_large: bool | None = None) -> bool:
    """True when overridable limits are lifted: by the argument, else by the environment."""
    if allow_large is not None:
        return bool(allow_large)
    return os.environ.get(ALLOW_LARGE_ENV, "").strip().lower() in ("1", "true", "yes", "on")


def override_hint() -> str:
    return f"pass --allow-large (or allow_large=True, or set {ALLOW_LARGE_ENV}=1) if you really want this"


def check_limit(what: str, value: float, limit: float, name: str, allow_large: bool | None = None,
                overridable: bool = True) -> None:
    """Raise `LimitError` when `value` exceeds `limit` (unless lifted); `what` names the input."""
    if value <= limit or (overridable and large_allowed(allow_large)):
        return
    hint = override_hint() if overridable else "this limit guards against malformed files and cannot be lifted"
    raise LimitError(f"{what}: {_fmt(value)} exceeds the limit {name} = {_fmt(limit)}; {hint}")


def check_file_size(path: str | Path, what: str, allow_large: bool | None = None, limit: int | None = None) -> int:
    """Size of `path` in bytes after checking it against `max_file_bytes` (or `limit`)."""
    from tryon.errors import InputFileError

    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise InputFileError(f"{what} {path}: cannot be read ({exc.strerror or exc})") from exc
    check_limit(f"{what} {path}", size, LIMITS.max_file_bytes if limit is None else limit, "max_file_bytes (bytes)",
                allow_large)
    return size


def run_memory_bytes(vertices: int, frames: int, obstacle_vertices: int = 0) -> int:
    """Rough peak memory (bytes) of simulating `vertices` cloth vertices and keeping `frames`
    frames: float64 positions per kept frame, about 4 KiB per vertex of solver state (sparse
    3x3 blocks, hinges, collision structures) and 1 KiB per obstacle vertex."""
    return 24 * vertices * max(frames, 1) + 4096 * vertices + 1024 * obstacle_vertices


def check_run(what: str, steps: int, frames: int, vertices: int, obstacle_vertices: int = 0,
              allow_large: bool | None = None) -> None:
    """The limits of one simulation run, checked together before it starts."""
    check_limit(f"{what}: steps (duration / dt)", steps, LIMITS.max_steps, "max_steps", allow_large)
    check_limit(f"{what}: frames (duration / frame_time)", frames, LIMITS.max_frames, "max_frames", allow_large)
    check_limit(f"{what}: cloth vertices", vertices, LIMITS.max_vertices, "max_vertices", allow_large)
    check_limit(f"{what}: obstacle vertices", obstacle_vertices, LIMITS.max_obstacle_vertices, "max_obstacle_vertices",
                allow_large)
    check_limit(f"{what}: estimated memory (bytes)", run_memory_bytes(vertices, frames, obstacle_vertices),
                LIMITS.max_memory_bytes, "max_memory_bytes", allow_large)


def _fmt(value: float) -> str:
    if isinstance(value, int) or float(value).is_integer() and abs(value) < 1e18:
        return f"{int(value):,}"
    return f"{value:.3g}"
