"""JSON outputs that are always valid JSON: NaN and infinities become null (Python's json
writes them as bare NaN / Infinity, which other readers reject)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from tryon.io.atomic import atomic_write


def json_safe(value: Any) -> Any:
    """`value` with numpy scalars/arrays made plain, tuples made lists, paths made text and
    non-finite floats replaced by None."""
    if isinstance(value, dict):
        return {str(k) if not isinstance(k, (str, int, float, bool)) and k is not None else k: json_safe(v)
                for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, np.generic):
        return json_safe(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value


def dumps_json(value: Any, **kwargs: Any) -> str:
    """`json.dumps` of `json_safe(value)`; never emits NaN or Infinity."""
    return json.dumps(json_safe(value), allow_nan=False, **kwargs)


def write_json(path: str | Path, value: Any, indent: int | None = 2) -> Path:
    """Write `value` as strict JSON (atomic)."""
    with atomic_write(path, "w") as fh:
        fh.write(dumps_json(value, indent=indent) + "\n")
    return Path(path)
