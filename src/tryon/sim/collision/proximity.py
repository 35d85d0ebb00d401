"""Proximity contacts: primitive pairs closer than the thickness h at one instant
(Bridson, Fedkiw & Anderson 2002, sec. 7; ARCSim's proximity.cpp, Narain et al. 2012).

Candidates come from a BVH over face boxes inflated by h/2: for every pair of overlapping
faces, each face tests the vertices and edges it owns (`topology.MeshTopology`), so every
vertex-face and edge-edge pair is tested once (ARCSim's scheme).

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

from tryon.sim.geometry.bvh import (
    _overlap,
    element_boxes,
    overlapping_pairs,
    point_boxes,
    swept_boxes,
    swept_point_boxes,
)
from tryon.sim.collision.contacts import (
    EE_OBSTACLE,
    EE_SELF,
    FV_OBSTACLE,
    VF_OBSTACLE,
    VF_SELF,
    Contacts,
    check_thickness,
)
from tryon.sim.geometry.inputs import check_finite, prepare_inputs
from tryon.sim.geometry.normals import obstacle_normals_near
from tryon.sim.geometry.threads import chunked
from tryon.sim.collision.topology import TreeCache, face_tree, mesh_topology
from tryon.sim.geometry.primitives import (
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
MODE_OBSTACLE = 1  # cloth vertex vs obstacle face, cloth edge vs obstacle edge
MODE_OBSTACLE_VERTEX = 2  # obstacle vertex vs cloth face
# |cos| below which an obstacle pseudonormal is too oblique to orient a contact normal
ORIENT_COS = 1e-3


# --------------------------------------------------------------------------- pair tests
@jit
def _vf_far(p, a, b, c, thickness):
    """Division-free early rejection (most candidates): True when p is certainly not
    within the thickness of abc's plane or does not project inside abc."""
    ab = sub(b, a)
    ac = sub(c, a)
    ap = sub(p, a)
    nn = cross(ab, ac)
    a2 = dot(nn, nn)
    hn = dot(ap, nn)
    if hn * hn >= thickness * thickness * a2:
        return True
    tol = 2.0 * INSIDE_TOL * a2  # loose: the exact test decides near the boundary
    b1n = dot(cross(ap, ac), nn)
    b2n = dot(cross(ab, ap), nn)
    return b1n < -tol or b2n < -tol or a2 - b1n - b2n < -tol


@jit
def _ee_far(p0, p1, q0, q1, thickness):
    """Division-free early rejection for edge pairs: the lines are at least the thickness
    apart (|r.(d1 x d2)|^2 >= h^2 |d1 x d2|^2), or their closest points are off the edges."""
    d1 = sub(p1, p0)
    d2 = sub(q1, q0)
    r = sub(p0, q0)
    a = dot(d1, d1)
    e = dot(d2, d2)
    b = dot(d1, d2)
    den = a * e - b * b
    vol = dot(r, cross(d1, d2))
    if vol * vol >= thickness * thickness * den:
        return True
    c = dot(d1, r)
    f = dot(d2, r)
    sn = b * f - c * e
    tn = a * f - b * c
    lo = -2.0 * INSIDE_TOL * den
    hi = (1.0 + 2.0 * INSIDE_TOL) * den
    return sn < lo or sn > hi or tn < lo or tn > hi


@jit
def vf_test(p, a, b, c, thickness, mode, vnormal):
    """Vertex p against triangle abc: (ok, gap, n, b0, b1, b2), ok when p projects inside
    the triangle within the thickness of its plane; n oriented as in the module docstring
    (vnormal: the obstacle vertex's pseudonormal for MODE_OBSTACLE_VERTEX)."""
    if _vf_far(p, a, b, c, thickness):
        return False, 0.0, (0.0, 0.0, 0.0), 0.0, 0.0, 0.0
    ok, h, n, b0, b1, b2 = plane_projection(p, a, b, c)
    if not ok or abs(h) >= thickness or b0 < -INSIDE_TOL or b1 < -INSIDE_TOL or b2 < -INSIDE_TOL:
        return False, h, n, b0, b1, b2
    if mode == MODE_SELF:
        if h < 0.0:
            return True, -h, scale(n, -1.0), b0, b1, b2
    elif mode == MODE_OBSTACLE_VERTEX:
        # the cloth is outside the obstacle: n points from the cloth face to the obstacle
        # vertex, i.e. against the vertex's outward pseudonormal
        s = dot(n, vnormal)
        if s > ORIENT_COS or (s >= -ORIENT_COS and h < 0.0):
            return True, -h, scale(n, -1.0), b0, b1, b2
    return True, h, n, b0, b1, b2


@jit
def ee_test(p0, p1, q0, q1, thickness, mode, enormal):
    """Edge p0p1 against edge q0q1: (ok, gap, n, s, t), ok when the closest points of the
    (non-parallel) lines lie on both segments closer than the thickness."""
    zero = (0.0, 0.0, 0.0)
    if _ee_far(p0, p1, q0, q1, thickness):
        return False, 0.0, zero, 0.0, 0.0
    ok, s, t = closest_points_lines(p0, p1, q0, q1)
    if not ok or s < -INSIDE_TOL or s > 1.0 + INSIDE_TOL or t < -INSIDE_TOL or t > 1.0 + INSIDE_TOL:
        return False, 0.0, zero, s, t
    s = min(max(s, 0.0), 1.0)
    t = min(max(t, 0.0), 1.0)
    nn = cross(sub(p1, p0), sub(q1, q0))
    n = scale(nn, 1.0 / norm(nn))
    h = dot(n, sub(lerp(p0, p1, s), lerp(q0, q1, t)))
    if abs(h) >= thickness:
        return False, h, n, s, t
    if mode == MODE_SELF:
        flip = h < 0.0
    else:
        so = dot(n, enormal)
        flip = so < -ORIENT_COS or (so <= ORIENT_COS and h < 0.0)
    if flip:
        return True, -h, scale(n, -1.0), s, t
    return True, h, n, s, t


# --------------------------------------------------------------------------- contact buffers
# Drivers write into preallocated buffers and stop when fewer than PER_PAIR slots are left;
# `run_driver` then grows the buffers and resumes (reassigning buffers inside a numba loop
# would make the whole loop 4x slower).
PER_PAIR = 15  # most contacts one face pair can produce: 3 + 3 vertex-face, 9 edge-edge


def new_contacts(cap: int) -> tuple:
    """Contact buffers (idx, w, n, d, kind, time)."""
    cap = max(int(cap), 64)
    return (np.empty((cap, 4), np.int64), np.empty((cap, 4)), np.empty((cap, 3)), np.empty(cap),
            np.empty(cap, np.int8), np.empty(cap))


def run_driver(driver, pairs: np.ndarray, *args) -> Contacts:
    """Run a contact driver over candidate pairs: in chunks on the worker threads when
    there are many (`chunked`), each chunk's contacts in pair order, so the result is the
    same for any number of threads."""
    return Contacts.concatenate(chunked(lambda part: _run_serial(driver, part, *args), pairs))


def _run_serial(driver, pairs: np.ndarray, *args) -> Contacts:
    """Run a contact driver over candidate pairs, growing its buffers until all fit."""
    buf = new_contacts(len(pairs) // 8 + PER_PAIR)
    m, nxt = driver(pairs, 0, 0, buf, *args)
    while nxt < len(pairs):
        buf = tuple(np.concatenate([b, np.empty_like(b)]) for b in buf)
        m, nxt = driver(pairs, nxt, m, buf, *args)
    idx, w, n, d, kind, t = buf
    return Contacts(idx[:m].copy(), w[:m].copy(), n[:m].copy(), d[:m].copy(), kind[:m].copy(), t[:m].copy())


@jit
def store(buf, m, i0, i1, i2, i3, w0, w1, w2, w3, n, d, kind, t):
    """Write contact m into the buffers."""
    idx, w, nn, dd, kk, tt = buf
    idx[m, 0] = i0
    idx[m, 1] = i1
    idx[m, 2] = i2
    idx[m, 3] = i3
    w[m, 0] = w0
    w[m, 1] = w1
    w[m, 2] = w2
    w[m, 3] = w3
    nn[m, 0] = n[0]
    nn[m, 1] = n[1]
    nn[m, 2] = n[2]
    dd[m] = d
    kk[m] = kind
    tt[m] = t


@jit
def _in_face(v, faces, f):
    # bitwise | rather than `or`: these tests are unpredictable, branches cost more
    return (v == faces[f, 0]) | (v == faces[f, 1]) | (v == faces[f, 2])


@jit
def _share(edges, e, g):
    return (edges[e, 0] == edges[g, 0]) | (edges[e, 0] == edges[g, 1]) | (edges[e, 1] == edges[g, 0]) | (edges[e, 1] == edges[g, 1])


# --------------------------------------------------------------------------- drivers
@jit
def self_proximities(pairs, start, m, buf, x, faces, edges, own_v, own_e, nv, ne, bx, thickness):
    """Self contacts of cloth from overlapping face pairs (A, B): the vertices owned by
    one face against the other face, and the edges owned by A against those owned by B.
    bx: primitive boxes (see `mesh_boxes`) that cull pairs before the exact tests.
    Processes pairs from `start` on; returns (contacts written, next pair)."""
    none = (0.0, 0.0, 0.0)
    cap = buf[0].shape[0]
    for c in range(start, pairs.shape[0]):
        if m + PER_PAIR > cap:
            return m, c
        for side in range(2):
            fa = pairs[c, side]
            fb = pairs[c, 1 - side]
            for k in range(nv[fa]):
                v = own_v[fa, k]
                if v < 0 or _in_face(v, faces, fb) or not _overlap(bx[0], bx[1], v, bx[4], bx[5], fb):
                    continue
                i0, i1, i2 = faces[fb, 0], faces[fb, 1], faces[fb, 2]
                ok, h, n, b0, b1, b2 = vf_test(row(x, v), row(x, i0), row(x, i1), row(x, i2), thickness, MODE_SELF, none)
                if ok:
                    store(buf, m, v, i0, i1, i2, 1.0, -b0, -b1, -b2, n, h, VF_SELF, 0.0)
                    m += 1
        for k in range(ne[pairs[c, 0]]):
            e = own_e[pairs[c, 0], k]
            for l_ in range(ne[pairs[c, 1]]):
                g = own_e[pairs[c, 1], l_]
                if _share(edges, e, g) or not _overlap(bx[2], bx[3], e, bx[2], bx[3], g):
                    continue
                a0, a1, c0, c1 = edges[e, 0], edges[e, 1], edges[g, 0], edges[g, 1]
                ok, h, n, s, t = ee_test(row(x, a0), row(x, a1), row(x, c0), row(x, c1), thickness, MODE_SELF, none)
                if ok:
                    store(buf, m, a0, a1, c0, c1, 1.0 - s, s, -(1.0 - t), -t, n, h, EE_SELF, 0.0)
                    m += 1
    return m, pairs.shape[0]


@jit
def obstacle_proximities(pairs, start, m, buf, x, faces, edges, own_v, own_e, nv, ne, bx, ob, ob_faces, ob_edges,
                         ob_own_v, ob_own_e, ob_nv, ob_ne, ob_bx, ob_vn, ob_en, thickness):
    """Cloth-obstacle contacts from overlapping (cloth face, obstacle face) pairs; as
    `self_proximities`."""
    none = (0.0, 0.0, 0.0)
    cap = buf[0].shape[0]
    for c in range(start, pairs.shape[0]):
        if m + PER_PAIR > cap:
            return m, c
        fa = pairs[c, 0]
        fb = pairs[c, 1]
        j0, j1, j2 = ob_faces[fb, 0], ob_faces[fb, 1], ob_faces[fb, 2]
        for k in range(3):
            v = own_v[fa, k]
            if v < 0 or not _overlap(bx[0], bx[1], v, ob_bx[4], ob_bx[5], fb):
                continue
            ok, h, n, b0, b1, b2 = vf_test(row(x, v), row(ob, j0), row(ob, j1), row(ob, j2), thickness, MODE_OBSTACLE, none)
            if ok:
                store(buf, m, v, -j0 - 1, -j1 - 1, -j2 - 1, 1.0, -b0, -b1, -b2, n, h, VF_OBSTACLE, 0.0)
                m += 1
        i0, i1, i2 = faces[fa, 0], faces[fa, 1], faces[fa, 2]
        for k in range(3):
            v = ob_own_v[fb, k]
            if v < 0 or not _overlap(ob_bx[0], ob_bx[1], v, bx[4], bx[5], fa):
                continue
            ok, h, n, b0, b1, b2 = vf_test(row(ob, v), row(x, i0), row(x, i1), row(x, i2), thickness, MODE_OBSTACLE_VERTEX, row(ob_vn, v))
            if ok:
                store(buf, m, -v - 1, i0, i1, i2, 1.0, -b0, -b1, -b2, n, h, FV_OBSTACLE, 0.0)
                m += 1
        for k in range(ne[fa]):
            e = own_e[fa, k]
            for l_ in range(ob_ne[fb]):
                g = ob_own_e[fb, l_]
                if not _overlap(bx[2], bx[3], e, ob_bx[2], ob_bx[3], g):
                    continue
                a0, a1, c0, c1 = edges[e, 0], edges[e, 1], ob_edges[g, 0], ob_edges[g, 1]
                ok, h, n, s, t = ee_test(row(x, a0), row(x, a1), row(ob, c0), row(ob, c1), thickness, MODE_OBSTACLE, row(ob_en, g))
                if ok:
                    store(buf, m, a0, a1, -c0 - 1, -c1 - 1, 1.0 - s, s, -(1.0 - t), -t, n, h, EE_OBSTACLE, 0.0)
                    m += 1
    return m, pairs.shape[0]


# --------------------------------------------------------------------------- assembly
def mesh_boxes(x: np.ndarray, faces: np.ndarray, edges: np.ndarray, margin: float, x1: np.ndarray | None = None) -> tuple:
    """Boxes of vertices (inflated by margin), edges (by margin / 2) and faces (exact), at x
    or swept from x to x1: two primitives within `margin` have overlapping boxes."""
    if x1 is None:
        return (*point_boxes(x, margin), *element_boxes(x, edges, 0.5 * margin), *element_boxes(x, faces, 0.0))
    return (*swept_point_boxes(x, x1, margin), *swept_boxes(x, x1, edges, 0.5 * margin), *swept_boxes(x, x1, faces, 0.0))


def find_proximities(
    x: Any,
    faces: Any,
    edges: Any,
    ob: Any,
    ob_faces: Any,
    ob_edges: Any,
    thickness: float,
    self_collision: bool = True,
    alias: np.ndarray | None = None,
    trees: TreeCache | None = None,
) -> Contacts:
    """All vertex-face and edge-edge pairs closer than `thickness` (criteria and normal
    orientation in the module docstring), found by traversing BVHs over face boxes
    inflated by thickness / 2, each face testing the vertices and edges it owns. Kinds:
    VF_SELF, EE_SELF (when self_collision), VF_OBSTACLE, FV_OBSTACLE, EE_OBSTACLE; d is the
    gap at x. Vertices sharing an `alias` (stitched ones) count as one vertex. `trees`: the
    BVH topology cache to use (a simulation's own; None: the one shared by queries outside
    simulations)."""
    x, faces, edges, ob, ob_faces, ob_edges = prepare_inputs(x, faces, edges, ob, ob_faces, ob_edges)
    check_finite(x, "cloth positions")
    check_finite(ob, "obstacle positions")
    h = check_thickness(thickness)
    topo = mesh_topology(faces, edges, len(x))
    bx = mesh_boxes(x, faces, edges, h)
    tris = face_tree(faces, bx[4] - 0.5 * h, bx[5] + 0.5 * h, trees)
    parts = []
    if self_collision:
        pairs = overlapping_pairs(tris)
        parts.append(run_driver(self_proximities, pairs, x, faces, edges, topo.own_vertices, topo.own_edges, topo.n_own_vertices, topo.n_own_edges, bx, h)
                     .without_joined(alias))
    if len(ob) and len(ob_faces):
        ob_topo = mesh_topology(ob_faces, ob_edges, len(ob))
        ob_bx = mesh_boxes(ob, ob_faces, ob_edges, h)
        ob_tris = face_tree(ob_faces, ob_bx[4] - 0.5 * h, ob_bx[5] + 0.5 * h, trees)
        pairs = overlapping_pairs(tris, ob_tris)
        ob_vn, ob_en = obstacle_normals_near(ob, ob_faces, ob_edges, pairs[:, 1])  # only where the pairs look
        parts.append(run_driver(
            obstacle_proximities, pairs, x, faces, edges, topo.own_vertices, topo.own_edges, topo.n_own_vertices, topo.n_own_edges, bx, ob, ob_faces,
            ob_edges, ob_topo.own_vertices, ob_topo.own_edges, ob_topo.n_own_vertices, ob_topo.n_own_edges, ob_bx, ob_vn, ob_en, h,
        ))
    return Contacts.concatenate(parts)
