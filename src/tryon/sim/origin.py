"""Where a scene's cloth came from, as plain data the simulator's tools can use without
knowing about garments: a grid, or a mesh triangulated from a sewing pattern.

Time-parallel simulation coarsens the cloth through this interface: a pattern origin can
triangulate its pattern again at another edge length (`remesh`), which the garment
package provides when it builds the scene.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class PatternMesh:
    """A pattern triangulated at some edge length with its seams welded: faces [F,3]
    (vertex ids 0..V-1), per-corner material coordinates [F,3,2] (m) and the pattern
    piece of each face [F]."""

    faces: np.ndarray
    corner_uv: np.ndarray
    face_panel: np.ndarray

    @property
    def num_vertices(self) -> int:
        return int(self.faces.max()) + 1 if len(self.faces) else 0


@dataclass(frozen=True)
class GridOrigin:
    """A rectangular grid of `resolution` vertices per side."""

    resolution: tuple[int, int]


@dataclass(frozen=True, eq=False)
class PatternOrigin:
    """A cloth triangulated from a sewing pattern at `edge_length` (m); `face_panel` [F]
    is the pattern piece of each of its faces, `remesh(edge_length)` the same pattern
    triangulated at another edge length."""

    edge_length: float
    face_panel: np.ndarray
    remesh: Callable[[float], PatternMesh]


ClothOrigin = GridOrigin | PatternOrigin
