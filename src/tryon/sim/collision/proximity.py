"""Proximity contacts: primitive pairs closer than the thickness h at one instant
(Bridson, Fedkiw & Anderson 2002, sec. 7; ARCSim's proximity.cpp, Narain et al. 2012).

Criteria (the ARCSim ones, which never report in-plane neighbours of a flat sheet):
- vertex-face: the vertex projects inside the face (barycentrics >= -1e-6) and its
  distance to the face plane is below h; n is the face normal;
- edge-edge: the edges are not parallel, the closest points of their lines lie on both
  segments (parameters in [-1e-6, 1 + 1e-6]) and are closer than h; n = e0 x e1 / |e0 x e1|.

Orientation of n: self contacts point towards the side the vertex / first edge is on
(so d >= 0); obstacle contacts use the obstacle's outward normal (face normal for
vertex-face, pseudonormal for obstacle edges and vertices), so d < 0 means penetration.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tryon.sim.collision.bvh import BVH, element_boxes, overlapping_pairs, point_boxes
from tryon.sim.collision.bvh import _grow as grow
from tryon.sim.collision.contacts import (
    EE_OBSTACLE,
    EE_SELF,
    FV_OBSTACLE,
    VF_OBSTACLE,
    VF_SELF,
    Contacts,
    as_index,
    as_points,
    check_finite,
    check_thickness,
)
from tryon.sim.collision.geometry import obstacle_normals
from tryon.sim.collision.primitives import (
    INSIDE_TOL,
    closest_points_lines,
    cross,
    dot,
    jit,
    lerp,
    norm,
    plane_projection,
    row,
    scale,
    sub,
)

MODE_SELF = 0
MODE_CLOTH_VERTEX_OBSTACLE_FACE = 1  # also: cloth edge vs obstacle edge
MODE_OBSTACLE_VERTEX_CLOTH_FACE = 2
# |cos| below which an obstacle pseudonormal is too oblique to orient a contact normal
ORIENT_COS = 1e-3


@jit
def vf_proximity(pairs, xv, xf, faces, thickness, mode, ob_vnormals):
    """Vertex-face proximity for candidate pairs (vertex id in xv, face id): returns the
    contacts found as (pair index [M], weights [M,4], normals [M,3], gaps [M])."""
    sel, w, n_out, d_out = new_buffers(pairs.shape[0])
    m = 0
    for c in range(pairs.shape[0]):
        v = pairs[c, 0]
        f = pairs[c, 1]
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        if mode == MODE_SELF and (v == i0 or v == i1 or v == i2):
            continue
        ok, h, n, b0, b1, b2 = plane_projection(row(xv, v), row(xf, i0), row(xf, i1), row(xf, i2))
        if not ok or abs(h) >= thickness:
            continue
        if b0 < -INSIDE_TOL or b1 < -INSIDE_TOL or b2 < -INSIDE_TOL:
            continue
        if mode == MODE_SELF:
            if h < 0.0:
                n = scale(n, -1.0)
                h = -h
        elif mode == MODE_OBSTACLE_VERTEX_CLOTH_FACE:
            # the cloth is outside the obstacle: n must point from the cloth to the obstacle
            # vertex, i.e. against the vertex's outward pseudonormal
            vnorm = row(ob_vnormals, v)
            if vnorm[0] == 0.0 and vnorm[1] == 0.0 and vnorm[2] == 0.0:
                continue  # an obstacle vertex on no face
            s = dot(n, vnorm)
            if s > ORIENT_COS or (s >= -ORIENT_COS and h < 0.0):
                n = scale(n, -1.0)
                h = -h
        if m == sel.shape[0]:
            sel, w, n_out, d_out = grow_buffers(sel, w, n_out, d_out)
        store(m, c, (1.0, -b0, -b1, -b2), n, h, sel, w, n_out, d_out)
        m += 1
    return sel[:m], w[:m], n_out[:m], d_out[:m]


@jit
def ee_proximity(pairs, xa, ea, xb, eb, thickness, mode, ob_enormals):
    """Edge-edge proximity for candidate pairs (edge id in ea, edge id in eb); same
    outputs as `vf_proximity`. mode SELF: xb is xa and eb is ea."""
    sel, w, n_out, d_out = new_buffers(pairs.shape[0])
    m = 0
    for c in range(pairs.shape[0]):
        e = pairs[c, 0]
        g = pairs[c, 1]
        a0, a1 = ea[e, 0], ea[e, 1]
        c0, c1 = eb[g, 0], eb[g, 1]
        if mode == MODE_SELF and (a0 == c0 or a0 == c1 or a1 == c0 or a1 == c1):
            continue
        p0 = row(xa, a0)
        p1 = row(xa, a1)
        q0 = row(xb, c0)
        q1 = row(xb, c1)
        ok, s, t = closest_points_lines(p0, p1, q0, q1)
        if not ok:
            continue
        if s < -INSIDE_TOL or s > 1.0 + INSIDE_TOL or t < -INSIDE_TOL or t > 1.0 + INSIDE_TOL:
            continue
        s = min(max(s, 0.0), 1.0)
        t = min(max(t, 0.0), 1.0)
        diff = sub(lerp(p0, p1, s), lerp(q0, q1, t))
        nn = cross(sub(p1, p0), sub(q1, q0))
        n = scale(nn, 1.0 / norm(nn))
        h = dot(n, diff)
        if abs(h) >= thickness:
            continue
        if mode == MODE_SELF:
            flip = h < 0.0
        else:
            so = dot(n, row(ob_enormals, g))
            flip = so < -ORIENT_COS or (so <= ORIENT_COS and h < 0.0)
        if flip:
            n = scale(n, -1.0)
            h = -h
        if m == sel.shape[0]:
            sel, w, n_out, d_out = grow_buffers(sel, w, n_out, d_out)
        store(m, c, (1.0 - s, s, -(1.0 - t), -t), n, h, sel, w, n_out, d_out)
        m += 1
    return sel[:m], w[:m], n_out[:m], d_out[:m]


@jit
def new_buffers(n_candidates):
    cap = max(16, n_candidates // 8)
    return np.empty(cap, np.int64), np.empty((cap, 4)), np.empty((cap, 3)), np.empty(cap)


@jit
def grow_buffers(sel, w, n, d):
    return grow(sel), grow(w), grow(n), grow(d)


@jit
def store(m, c, ww, n, d, sel, w, n_out, d_out):
    sel[m] = c
    for k in range(4):
        w[m, k] = ww[k]
    for k in range(3):
        n_out[m, k] = n[k]
    d_out[m] = d


# --------------------------------------------------------------------------- assembly
def obstacle_id(i: np.ndarray) -> np.ndarray:
    """Contact id of obstacle vertex i: -i-1."""
    return -np.asarray(i, np.int64) - 1


def make_contacts(out: tuple, pairs: np.ndarray, ids_of, kind: int, time: np.ndarray | None = None) -> Contacts:
    """Contacts from a kernel's outputs (sel, w, n, d): `ids_of(pairs[sel])` gives their
    global point ids [M,4]."""
    sel, w, n, d = out
    m = len(sel)
    t = np.zeros(m) if time is None else time
    return Contacts(np.ascontiguousarray(ids_of(pairs[sel]), dtype=np.int64), w, n, d, np.full(m, kind, np.int8), t)


def vf_ids(vertex_ids: np.ndarray, face_vertex_ids: np.ndarray) -> np.ndarray:
    return np.concatenate([vertex_ids[:, None], face_vertex_ids], 1).astype(np.int64)


def prepare_inputs(x, faces, edges, ob, ob_faces, ob_edges):
    """Validated numpy arrays (positions float64 [.,3], ids int64) for the collision API."""
    x = as_points(x, "cloth positions")
    faces = as_index(faces, 3, "cloth faces", len(x))
    edges = as_index(edges, 2, "cloth edges", len(x))
    ob = as_points(ob if ob is not None else np.zeros((0, 3)), "obstacle positions")
    ob_faces = as_index(ob_faces, 3, "obstacle faces", max(len(ob), 1)) if len(ob) else np.zeros((0, 3), np.int64)
    ob_edges = as_index(ob_edges, 2, "obstacle edges", max(len(ob), 1)) if len(ob) else np.zeros((0, 2), np.int64)
    return x, faces, edges, ob, ob_faces, ob_edges


def find_proximities(
    x: Any,
    faces: Any,
    edges: Any,
    ob: Any,
    ob_faces: Any,
    ob_edges: Any,
    thickness: float,
    self_collision: bool = True,
) -> Contacts:
    """All vertex-face and edge-edge pairs closer than `thickness` (see the module
    docstring for the criteria and normal orientation), found through BVHs over boxes
    inflated by the thickness. Kinds: VF_SELF, EE_SELF (when self_collision), VF_OBSTACLE,
    FV_OBSTACLE, EE_OBSTACLE. d is the gap at x."""
    x, faces, edges, ob, ob_faces, ob_edges = prepare_inputs(x, faces, edges, ob, ob_faces, ob_edges)
    check_finite(x, "cloth positions")
    check_finite(ob, "obstacle positions")
    h = check_thickness(thickness)
    none3 = np.zeros((1, 3))
    verts = BVH.build(*point_boxes(x, h))
    tris = BVH.build(*element_boxes(x, faces, 0.0))
    segs = BVH.build(*element_boxes(x, edges, 0.5 * h))
    parts = []
    if self_collision:
        p = overlapping_pairs(verts, tris)
        out = vf_proximity(p, x, x, faces, h, MODE_SELF, none3)
        parts.append(make_contacts(out, p, lambda q: vf_ids(q[:, 0], faces[q[:, 1]]), VF_SELF))
        p = overlapping_pairs(segs)
        out = ee_proximity(p, x, edges, x, edges, h, MODE_SELF, none3)
        parts.append(make_contacts(out, p, lambda q: np.concatenate([edges[q[:, 0]], edges[q[:, 1]]], 1), EE_SELF))
    if len(ob) and len(ob_faces):
        ob_vn, ob_en = obstacle_normals(ob, ob_faces, ob_edges)
        ob_tris = BVH.build(*element_boxes(ob, ob_faces, 0.0))
        p = overlapping_pairs(verts, ob_tris)
        out = vf_proximity(p, x, ob, ob_faces, h, MODE_CLOTH_VERTEX_OBSTACLE_FACE, none3)
        parts.append(make_contacts(out, p, lambda q: vf_ids(q[:, 0], obstacle_id(ob_faces[q[:, 1]])), VF_OBSTACLE))
        ob_verts = BVH.build(*point_boxes(ob, h))
        p = overlapping_pairs(ob_verts, tris)
        out = vf_proximity(p, ob, x, faces, h, MODE_OBSTACLE_VERTEX_CLOTH_FACE, ob_vn)
        parts.append(make_contacts(out, p, lambda q: vf_ids(obstacle_id(q[:, 0]), faces[q[:, 1]]), FV_OBSTACLE))
        if len(ob_edges):
            ob_segs = BVH.build(*element_boxes(ob, ob_edges, 0.5 * h))
            p = overlapping_pairs(segs, ob_segs)
            out = ee_proximity(p, x, edges, ob, ob_edges, h, MODE_CLOTH_VERTEX_OBSTACLE_FACE, ob_en)
            ids_of = lambda q: np.concatenate([edges[q[:, 0]], obstacle_id(ob_edges[q[:, 1]])], 1)  # noqa: E731
            parts.append(make_contacts(out, p, ids_of, EE_OBSTACLE))
    return Contacts.concatenate(parts)
