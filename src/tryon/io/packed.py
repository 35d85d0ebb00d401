"""Arrays packed one after another into a binary file the browser reads (the viewer's and
the service page's scenes): little-endian float32 / uint32, laid out by name."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tryon.io.atomic import atomic_write


def packed_layout(arrays: list[tuple[str, np.ndarray]]) -> dict[str, dict]:
    """Each array's byte offset, element count and type in the packed file."""
    layout, offset = {}, 0
    for name, a in arrays:
        if a.dtype.kind not in "uf":
            raise ValueError(f"{name}: pack float or unsigned integer arrays, not {a.dtype}")
        layout[name] = {"offset": offset, "count": int(a.size), "type": "uint32" if a.dtype.kind == "u" else "float32"}
        offset += a.size * 4
    return layout


def write_packed(path: str | Path, arrays: list[tuple[str, np.ndarray]]) -> None:
    """The arrays, as float32 or uint32 (by kind), little-endian, one after another."""
    with atomic_write(Path(path), "wb") as fh:
        for _, a in arrays:
            fh.write(np.ascontiguousarray(a, dtype="<u4" if a.dtype.kind == "u" else "<f4").tobytes())
