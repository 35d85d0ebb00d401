"""Discrete checks of a configuration: edge-triangle intersections and distances from cloth
vertices to the obstacle surface (signed with angle-weighted pseudonormals, Baerentzen &
Aanaes 2005)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from tryon.sim.geometry.bvh import BVH, _box_dist2, element_boxes, overlapping_pairs
from tryon.sim.geometry.normals import cached_face_edge_ids, cached_mesh_edges, face_normals, obstacle_normals_near
from tryon.sim.geometry.primitives import jit, point_triangle_distance, row, segment_triangle_intersect
from tryon.sim.geometry.inputs import as_index, as_points, check_finite, prepare_inputs

# plane-side tolerance (m) of the discrete test: an edge must cross the face plane by more
# than this, so coplanar neighbours of a flat sheet never count as intersecting
CROSS_TOL = 1e-12


@jit
def edge_face_hits(pairs, xe, edges, xf, faces, same, tol):
    """Mask [K] of candidate (edge, face) pairs whose segment crosses the triangle; with
    same=True pairs sharing a vertex are skipped."""
    k = pairs.shape[0]
    hit = np.zeros(k, np.bool_)
    for c in range(k):
        e = pairs[c, 0]
        f = pairs[c, 1]
        a, b = edges[e, 0], edges[e, 1]
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        if same and (a == i0 or a == i1 or a == i2 or b == i0 or b == i1 or b == i2):
            continue
        hit[c] = segment_triangle_intersect(row(xe, a), row(xe, b), row(xf, i0), row(xf, i1), row(xf, i2), tol)
    return hit


def edge_face_intersections(x, edges, xf, faces, same: bool, alias: np.ndarray | None = None) -> np.ndarray:
    """Pairs [K,2] (edge id, face id) of intersecting edges and faces, found through BVHs;
    with same=True, an edge and a face whose vertices share an `alias` (stitched vertices)
    do not count."""
    if len(edges) == 0 or len(faces) == 0:
        return np.zeros((0, 2), np.int64)
    segs = BVH.build(*element_boxes(x, edges, 0.0))
    tris = BVH.build(*element_boxes(xf, faces, 0.0))
    pairs = overlapping_pairs(segs, tris)
    hits = pairs[edge_face_hits(pairs, x, edges, xf, faces, same, CROSS_TOL)]
    if same and alias is not None and len(hits):
        a, b = alias[edges[hits[:, 0]]], alias[faces[hits[:, 1]]]
        hits = hits[~(a[:, :, None] == b[:, None, :]).any(axis=(1, 2))]
    return hits


def count_intersections(
    x: Any, faces: Any, edges: Any, ob: Any, ob_faces: Any, ob_edges: Any, self_collision: bool = True,
    alias: np.ndarray | None = None,
) -> tuple[int, int]:
    """(self, obstacle) counts of intersecting (edge, triangle) pairs: cloth edges through
    cloth faces they do not share a vertex with (when self_collision), plus cloth edges
    through obstacle faces and obstacle edges through cloth faces."""
    x, faces, edges, ob, ob_faces, ob_edges = prepare_inputs(x, faces, edges, ob, ob_faces, ob_edges)
    check_finite(x, "cloth positions")
    n_self = len(edge_face_intersections(x, edges, x, faces, True, alias)) if self_collision else 0
    n_ob = 0
    if len(ob) and len(ob_faces):
        n_ob += len(edge_face_intersections(x, edges, ob, ob_faces, False))
        n_ob += len(edge_face_intersections(ob, ob_edges, x, faces, False))
    return int(n_self), int(n_ob)


# --------------------------------------------------------------------------- distances
@jit
def nearest_faces(points, xf, faces, order, child, first, count, nlo, nhi, lo, hi):
    """Nearest face of every point by best-first BVH descent with box-distance pruning:
    returns distance [N], face id [N] and barycentrics [N,3] of the closest point."""
    n = points.shape[0]
    dist = np.full(n, np.inf)
    face = np.full(n, -1, np.int64)
    bary = np.zeros((n, 3))
    stack = np.empty(256, np.int64)
    for i in range(n):
        p = row(points, i)
        best2 = np.inf
        stack[0] = 0
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack[sp]
            if _box_dist2(nlo, nhi, node, p) >= best2:
                continue
            if child[node, 0] < 0:
                for j in range(first[node], first[node] + count[node]):
                    f = order[j]
                    d, b0, b1, b2 = point_triangle_distance(p, row(xf, faces[f, 0]), row(xf, faces[f, 1]), row(xf, faces[f, 2]))
                    if d * d < best2:
                        best2 = d * d
                        face[i] = f
                        bary[i, 0] = b0
                        bary[i, 1] = b1
                        bary[i, 2] = b2
                continue
            a = child[node, 0]
            b = child[node, 1]
            if sp + 2 > stack.shape[0]:
                bigger = np.empty(2 * stack.shape[0], np.int64)
                bigger[:sp] = stack[:sp]
                stack = bigger
            # push the farther child first so that the nearer one is searched first
            if _box_dist2(nlo, nhi, a, p) < _box_dist2(nlo, nhi, b, p):
                stack[sp] = b
                stack[sp + 1] = a
            else:
                stack[sp] = a
                stack[sp + 1] = b
            sp += 2
        dist[i] = np.sqrt(best2)
    return dist, face, bary


def _nearest(x: np.ndarray, ob: np.ndarray, ob_faces: np.ndarray):
    tree = BVH.build(*element_boxes(ob, ob_faces, 0.0))
    return nearest_faces(x, ob, ob_faces, *tree.arrays())


def min_obstacle_distance(x: Any, ob: Any, ob_faces: Any) -> float:
    """Smallest unsigned distance (m) from a cloth vertex to the obstacle surface (inf
    without obstacle)."""
    x = as_points(x, "cloth positions")
    ob = as_points(ob if ob is not None else np.zeros((0, 3)), "obstacle positions")
    if len(ob) == 0 or len(x) == 0:
        return float("inf")
    ob_faces = as_index(ob_faces, 3, "obstacle faces", len(ob))
    if len(ob_faces) == 0:
        return float("inf")
    return float(_nearest(x, ob, ob_faces)[0].min())


def signed_obstacle_distance(x: Any, ob: Any, ob_faces: Any, ob_normals: Any = None) -> np.ndarray:
    """Signed distance [N] from every cloth vertex to the obstacle surface, negative inside.
    The sign comes from the outward pseudonormal of the nearest feature (face, edge or
    vertex, which is exact for closed meshes); pass `ob_normals` [Fo,3] to use given face
    normals of the nearest face instead."""
    x = as_points(x, "cloth positions")
    ob = as_points(ob if ob is not None else np.zeros((0, 3)), "obstacle positions")
    if len(ob) == 0:
        return np.full(len(x), np.inf)
    ob_faces = as_index(ob_faces, 3, "obstacle faces", len(ob))
    dist, face, bary = _nearest(x, ob, ob_faces)
    q = np.einsum("nk,nkd->nd", bary, ob[ob_faces[face]])
    if ob_normals is not None:
        normal = as_points(ob_normals, "obstacle face normals")[face]
    else:
        normal = _pseudonormal(ob, ob_faces, face, bary)
    side = np.sign(np.sum((x - q) * normal, 1))
    side[side == 0] = 1.0
    return side * dist


def _pseudonormal(ob: np.ndarray, ob_faces: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Pseudonormal of the feature of `face` holding the closest point: the face normal in
    the interior, the edge or vertex pseudonormal on its boundary."""
    nf = face_normals(ob, ob_faces)
    out = nf[face].copy()
    zero = bary == 0.0
    n_zero = zero.sum(1)
    on_vertex, on_edge = n_zero == 2, n_zero == 1
    if on_vertex.any() or on_edge.any():
        edges = cached_mesh_edges(ob_faces)
        vn, en = obstacle_normals_near(ob, ob_faces, edges, face[on_vertex | on_edge])
        if on_vertex.any():
            corner = np.argmax(bary[on_vertex], 1)
            out[on_vertex] = vn[ob_faces[face[on_vertex], corner]]
        if on_edge.any():
            fe = cached_face_edge_ids(ob_faces, edges)
            slot = (np.argmax(zero[on_edge], 1) + 1) % 3  # edge (v_k, v_k+1) lies opposite corner k+2
            out[on_edge] = en[fe[face[on_edge], slot]]
    return out


def nearest_surface_points(x: Any, ob: Any, ob_faces: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every point: signed distance [N] (negative inside), closest surface point [N,3]
    and the outward pseudonormal there [N,3]."""
    x = as_points(x, "points")
    ob = as_points(ob, "obstacle positions")
    ob_faces = as_index(ob_faces, 3, "obstacle faces", len(ob))
    dist, face, bary = _nearest(x, ob, ob_faces)
    q = np.einsum("nk,nkd->nd", bary, ob[ob_faces[face]])
    normal = _pseudonormal(ob, ob_faces, face, bary)
    side = np.sign(np.sum((x - q) * normal, 1))
    side[side == 0] = 1.0
    return side * dist, q, normal


def push_outside(x: Any, surface_vertices: Any, surface_faces: Any, gap: float | Sequence[float],
                 accept: Callable[[np.ndarray], bool] | None = None, max_depth: float = np.inf,
                 fixed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Points nearer the surface than `gap` (or inside it, at most `max_depth` deep: deeper
    points are behind an open surface, not in it) moved out along the surface's
    pseudonormal to `gap`; `fixed` (a mask or indices) never move. With several gaps, the
    smallest one whose result `accept` takes (e.g. "no crossing left") is used, else the
    largest. Returns (positions [N,3], moved mask [N], the gap used)."""
    gaps = sorted([float(gap)] if np.ndim(gap) == 0 else [float(g) for g in gap])
    if not gaps:
        raise ValueError("push_outside needs at least one gap")
    x = as_points(x, "points")
    d, q, n = nearest_surface_points(x, surface_vertices, surface_faces)
    for g in gaps:
        moved = (d < g) & (d > -max_depth)
        if fixed is not None:
            moved[fixed] = False
        out = np.where(moved[:, None], q + g * n, x)
        if accept is None or accept(out):
            break
    return out, moved, g


def nearest_surface_locations(x: Any, surface_vertices: Any, surface_faces: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every point: unsigned distance [N] to the surface, the nearest face [N] and the
    barycentric coordinates [N,3] of the nearest point on it (to follow a deforming surface)."""
    x = as_points(x, "points")
    ob = as_points(surface_vertices, "surface positions")
    faces = as_index(surface_faces, 3, "surface faces", len(ob))
    return _nearest(x, ob, faces)
