"""Checked inputs of the geometric queries: positions as float64 [N,3] and vertex ids as
int64 [K,width] (numpy or torch in), finite, ids inside the mesh, so that the compiled
kernels (which do not check bounds) never read outside their arrays."""

from __future__ import annotations

from typing import Any

import numpy as np

from tryon.errors import MeshError


def as_points(a: Any, name: str) -> np.ndarray:
    """Float64 C-contiguous [N,3] numpy array from numpy or torch input."""
    if hasattr(a, "detach"):
        a = a.detach().cpu().numpy()
    arr = np.ascontiguousarray(np.asarray(a, dtype=np.float64))
    if arr.size == 0:
        return arr.reshape(0, 3)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise MeshError(f"{name}: expected positions of shape [N,3], got {list(arr.shape)}")
    return arr


def as_index(a: Any, width: int, name: str, n_vertices: int) -> np.ndarray:
    """Int64 C-contiguous [K,width] index array, checked against n_vertices."""
    if a is None:
        return np.zeros((0, width), np.int64)
    if hasattr(a, "detach"):
        a = a.detach().cpu().numpy()
    arr = np.ascontiguousarray(np.asarray(a, dtype=np.int64))
    if arr.size == 0:
        return arr.reshape(0, width)
    if arr.ndim != 2 or arr.shape[1] != width:
        raise MeshError(f"{name}: expected an index array of shape [K,{width}], got {list(arr.shape)}")
    if arr.min() < 0 or arr.max() >= n_vertices:
        raise MeshError(f"{name}: vertex ids must lie in [0, {n_vertices}), got [{arr.min()}, {arr.max()}]; check the mesh")
    return arr


def check_finite(a: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(a)):
        raise MeshError(f"{name}: positions contain NaN or infinity; fix the input (or retry the step with a smaller dt)")


def prepare_inputs(x, faces, edges, ob, ob_faces, ob_edges):
    """Validated numpy arrays (positions float64 [.,3], ids int64) for the collision API."""
    x = as_points(x, "cloth positions")
    faces = as_index(faces, 3, "cloth faces", len(x))
    edges = as_index(edges, 2, "cloth edges", len(x))
    ob = as_points(ob if ob is not None else np.zeros((0, 3)), "obstacle positions")
    ob_faces = as_index(ob_faces, 3, "obstacle faces", max(len(ob), 1)) if len(ob) else np.zeros((0, 3), np.int64)
    ob_edges = as_index(ob_edges, 2, "obstacle edges", max(len(ob), 1)) if len(ob) else np.zeros((0, 2), np.int64)
    return x, faces, edges, ob, ob_faces, ob_edges
