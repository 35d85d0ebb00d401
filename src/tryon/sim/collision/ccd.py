"""Continuous collision detection between the start and end positions of a step, every
point moving linearly (Provot 1997; Bridson, Fedkiw & Anderson 2002, sec. 4).

Candidates come from a BVH over the swept boxes of faces (each face testing the vertices
and edges it owns, see `proximity`). For each candidate pair, the times when the four points are
coplanar are the roots of a cubic; the earliest candidate time at which the primitives
are also within a small distance `eps` of each other is the time of impact. Each impact
becomes a contact evaluated at that time, its normal oriented against the relative
normal motion (ARCSim's collision.cpp), i.e. towards the side the primitives started on.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tryon.sim.geometry.bvh import _overlap, overlapping_pairs
from tryon.errors import MeshError
from tryon.sim.collision.contacts import (
    check_thickness,
    EE_OBSTACLE,
    EE_SELF,
    FV_OBSTACLE,
    VF_OBSTACLE,
    VF_SELF,
    Contacts,
)
from tryon.sim.geometry.inputs import as_points, check_finite, prepare_inputs
from tryon.sim.geometry.primitives import (
    add,
    closest_points_segments,
    coplanarity_cubic,
    cross,
    cubic_candidate_times,
    dot,
    eval_cubic,
    jit,
    lerp,
    norm,
    point_triangle_distance,
    row,
    scale,
    sub,
    combine3,
)
from tryon.sim.collision.proximity import PER_PAIR, _in_face, _share, mesh_boxes, run_driver, store
from tryon.sim.collision.topology import TreeCache, face_tree, mesh_topology

# distance (m) at a coplanarity time below which two primitives count as touching
CCD_EPS = 1e-6


@jit
def _orient(n, rel_motion, start_gap):
    """+1 or -1 so that the oriented normal opposes the relative normal motion (the gap
    sum_k w_k n.p_k decreases towards the impact), else keeps the start gap positive."""
    vn = dot(n, rel_motion)
    if vn > 1e-300:
        return -1.0
    if vn < -1e-300:
        return 1.0
    return -1.0 if start_gap < 0.0 else 1.0


@jit
def _weighted(w0, w1, w2, w3, a, b, c, d):
    return add(add(scale(a, w0), scale(b, w1)), add(scale(c, w2), scale(d, w3)))


@jit
def vf_impact(p0, p1, a0, a1, b0, b1, q0, q1, eps, ts):
    """Earliest impact of vertex p against triangle abq, all moving linearly from *0 to *1:
    (ok, toi, n, u0, u1, u2, gap at toi); u the barycentrics of the contact point."""
    da = sub(a1, a0)
    co = coplanarity_cubic(
        sub(b0, a0), sub(q0, a0), sub(p0, a0), sub(sub(b1, b0), da), sub(sub(q1, q0), da), sub(sub(p1, p0), da)
    )
    nt = cubic_candidate_times(co[0], co[1], co[2], co[3], ts)
    for j in range(nt):
        t = ts[j]
        a, b, q, p = lerp(a0, a1, t), lerp(b0, b1, t), lerp(q0, q1, t), lerp(p0, p1, t)
        nn = cross(sub(b, a), sub(q, a))
        area2 = norm(nn)
        if area2 <= 1e-300 or abs(eval_cubic(co[0], co[1], co[2], co[3], t)) > eps * area2 * (1.0 + 1e-9):
            continue  # degenerate, or farther than eps from the face plane
        dist, u0, u1, u2 = point_triangle_distance(p, a, b, q)
        if dist >= eps:
            continue
        n = scale(nn, 1.0 / area2)
        rel = sub(sub(p1, p0), combine3(u0, u1, u2, sub(a1, a0), sub(b1, b0), sub(q1, q0)))
        gap0 = dot(n, sub(p0, combine3(u0, u1, u2, a0, b0, q0)))
        n = scale(n, _orient(n, rel, gap0))
        return True, t, n, u0, u1, u2, dot(n, sub(p, combine3(u0, u1, u2, a, b, q)))
    return False, 0.0, (0.0, 0.0, 0.0), 0.0, 0.0, 0.0, 0.0


@jit
def ee_impact(p0, p1, r0, r1, q0, q1, s0, s1, eps, ts):
    """Earliest impact of edge pr against edge qs, moving linearly from *0 to *1:
    (ok, toi, n, a, b, gap at toi); a, b the parameters of the contact points."""
    dp = sub(p1, p0)
    co = coplanarity_cubic(
        sub(r0, p0), sub(q0, p0), sub(s0, p0), sub(sub(r1, r0), dp), sub(sub(q1, q0), dp), sub(sub(s1, s0), dp)
    )
    nt = cubic_candidate_times(co[0], co[1], co[2], co[3], ts)
    for j in range(nt):
        t = ts[j]
        p, r, q, s = lerp(p0, p1, t), lerp(r0, r1, t), lerp(q0, q1, t), lerp(s0, s1, t)
        nn = cross(sub(r, p), sub(s, q))
        len_nn = norm(nn)
        if abs(eval_cubic(co[0], co[1], co[2], co[3], t)) > eps * len_nn * (1.0 + 1e-9) + 1e-300:
            continue  # the lines are farther apart than eps
        a, b = closest_points_segments(p, r, q, s)
        diff = sub(lerp(p, r, a), lerp(q, s, b))
        dist = norm(diff)
        if dist >= eps:
            continue
        rel = _weighted(1.0 - a, a, -(1.0 - b), -b, sub(p1, p0), sub(r1, r0), sub(q1, q0), sub(s1, s0))
        diff0 = _weighted(1.0 - a, a, -(1.0 - b), -b, p0, r0, q0, s0)
        dist0 = norm(diff0)
        if len_nn > 1e-3 * norm(sub(r, p)) * norm(sub(s, q)):
            n = scale(nn, 1.0 / len_nn)
        elif dist > 1e-300:
            n = scale(diff, 1.0 / dist)  # (nearly) parallel edges: the separation direction
        else:
            continue  # parallel and touching: the vertex-face tests of their ends apply
        at_end = a <= 1e-9 or a >= 1.0 - 1e-9 or b <= 1e-9 or b >= 1.0 - 1e-9
        grazing = abs(dot(n, rel)) < 0.1 * norm(rel) and abs(dot(n, diff0)) < 0.1 * dist0
        if (at_end or grazing) and dist0 > eps:
            # a vertex meets an edge, or the edges graze (e.g. cloth falling past a box's
            # vertical edge onto its corner): the lines' common normal neither opposes the
            # motion nor separates the start positions, so its sign is a coin toss and
            # contradicts the neighbouring contacts; the direction the points started
            # apart in separates them consistently
            n = scale(diff0, 1.0 / dist0)
        n = scale(n, _orient(n, rel, dot(n, diff0)))
        return True, t, n, a, b, dot(n, diff)
    return False, 0.0, (0.0, 0.0, 0.0), 0.0, 0.0, 0.0


@jit
def _vf_pair(buf, m, xv0, xv1, v, xf0, xf1, faces, f, vid, fsign, kind, eps, ts):
    """Test vertex v (contact id vid) against face f (obstacle ids when fsign < 0); store
    the impact; returns the new contact count."""
    i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
    ok, t, n, u0, u1, u2, d = vf_impact(
        row(xv0, v), row(xv1, v), row(xf0, i0), row(xf1, i0), row(xf0, i1), row(xf1, i1), row(xf0, i2), row(xf1, i2), eps, ts
    )
    if ok:
        if fsign < 0:
            i0, i1, i2 = -i0 - 1, -i1 - 1, -i2 - 1
        store(buf, m, vid, i0, i1, i2, 1.0, -u0, -u1, -u2, n, d, kind, t)
        m += 1
    return m


@jit
def self_impacts(pairs, start, m, buf, x0, x1, faces, edges, own_v, own_e, nv, ne, bx, eps):
    """Self impacts of cloth from overlapping swept face pairs (see `self_proximities`)."""
    ts = np.empty(8)
    cap = buf[0].shape[0]
    for c in range(start, pairs.shape[0]):
        if m + PER_PAIR > cap:
            return m, c
        for side in range(2):
            fa = pairs[c, side]
            fb = pairs[c, 1 - side]
            for k in range(nv[fa]):
                v = own_v[fa, k]
                if v >= 0 and not _in_face(v, faces, fb) and _overlap(bx[0], bx[1], v, bx[4], bx[5], fb):
                    m = _vf_pair(buf, m, x0, x1, v, x0, x1, faces, fb, v, 1, VF_SELF, eps, ts)
        for k in range(ne[pairs[c, 0]]):
            e = own_e[pairs[c, 0], k]
            for l_ in range(ne[pairs[c, 1]]):
                g = own_e[pairs[c, 1], l_]
                if _share(edges, e, g) or not _overlap(bx[2], bx[3], e, bx[2], bx[3], g):
                    continue
                a0, a1, c0, c1 = edges[e, 0], edges[e, 1], edges[g, 0], edges[g, 1]
                ok, t, n, a, b, d = ee_impact(
                    row(x0, a0), row(x1, a0), row(x0, a1), row(x1, a1), row(x0, c0), row(x1, c0), row(x0, c1), row(x1, c1), eps, ts
                )
                if ok:
                    store(buf, m, a0, a1, c0, c1, 1.0 - a, a, -(1.0 - b), -b, n, d, EE_SELF, t)
                    m += 1
    return m, pairs.shape[0]


@jit
def obstacle_impacts(pairs, start, m, buf, x0, x1, faces, edges, own_v, own_e, nv, ne, bx, ob0, ob1, ob_faces, ob_edges,
                     ob_own_v, ob_own_e, ob_nv, ob_ne, ob_bx, eps):
    """Cloth-obstacle impacts from overlapping swept (cloth face, obstacle face) pairs."""
    ts = np.empty(8)
    cap = buf[0].shape[0]
    for c in range(start, pairs.shape[0]):
        if m + PER_PAIR > cap:
            return m, c
        fa = pairs[c, 0]
        fb = pairs[c, 1]
        for k in range(3):
            v = own_v[fa, k]
            if v >= 0 and _overlap(bx[0], bx[1], v, ob_bx[4], ob_bx[5], fb):
                m = _vf_pair(buf, m, x0, x1, v, ob0, ob1, ob_faces, fb, v, -1, VF_OBSTACLE, eps, ts)
            v = ob_own_v[fb, k]
            if v >= 0 and _overlap(ob_bx[0], ob_bx[1], v, bx[4], bx[5], fa):
                m = _vf_pair(buf, m, ob0, ob1, v, x0, x1, faces, fa, -v - 1, 1, FV_OBSTACLE, eps, ts)
        for k in range(ne[fa]):
            e = own_e[fa, k]
            for l_ in range(ob_ne[fb]):
                g = ob_own_e[fb, l_]
                if not _overlap(bx[2], bx[3], e, ob_bx[2], ob_bx[3], g):
                    continue
                a0, a1, c0, c1 = edges[e, 0], edges[e, 1], ob_edges[g, 0], ob_edges[g, 1]
                ok, t, n, a, b, d = ee_impact(
                    row(x0, a0), row(x1, a0), row(x0, a1), row(x1, a1), row(ob0, c0), row(ob1, c0), row(ob0, c1), row(ob1, c1), eps, ts
                )
                if ok:
                    store(buf, m, a0, a1, -c0 - 1, -c1 - 1, 1.0 - a, a, -(1.0 - b), -b, n, d, EE_OBSTACLE, t)
                    m += 1
    return m, pairs.shape[0]


def find_impacts(
    x0: Any,
    x1: Any,
    faces: Any,
    edges: Any,
    ob0: Any,
    ob1: Any,
    ob_faces: Any,
    ob_edges: Any,
    thickness: float,
    self_collision: bool = True,
    eps: float = CCD_EPS,
    alias: np.ndarray | None = None,
    trees: TreeCache | None = None,
) -> Contacts:
    """Vertex-face and edge-edge impacts while cloth moves linearly x0 -> x1 and the
    obstacle ob0 -> ob1: for every primitive pair whose swept boxes overlap, the earliest
    time t in [0, 1] at which the points are coplanar (Provot's cubic) and within `eps`
    metres of each other. Each impact is a contact with weights and normal at time t
    (`time` = t, `d` = gap at t), n oriented towards the side the primitives came from.

    `thickness` is the contact thickness h of the scene; CCD itself looks for touching
    (distance < eps, default 1e-6 m, at most h / 10), not for proximity. Vertices sharing
    an `alias` (stitched ones) count as one vertex. `trees`: the BVH topology cache to use (a
    simulation's own; None: the one shared by queries outside simulations)."""
    x0, faces, edges, ob0, ob_faces, ob_edges = prepare_inputs(x0, faces, edges, ob0, ob_faces, ob_edges)
    x1 = as_points(x1, "cloth end positions")
    ob1 = as_points(ob1 if ob1 is not None else np.zeros((0, 3)), "obstacle end positions")
    if x1.shape != x0.shape or ob1.shape != ob0.shape:
        raise MeshError(
            f"start and end positions differ in shape: cloth {list(x0.shape)} vs {list(x1.shape)}, "
            f"obstacle {list(ob0.shape)} vs {list(ob1.shape)}"
        )
    for a, name in ((x0, "cloth start positions"), (x1, "cloth end positions"), (ob0, "obstacle start positions"), (ob1, "obstacle end positions")):
        check_finite(a, name)
    eps = min(float(eps), 0.1 * check_thickness(thickness))
    topo = mesh_topology(faces, edges, len(x0))
    bx = mesh_boxes(x0, faces, edges, eps, x1)
    tris = face_tree(faces, bx[4] - 0.5 * eps, bx[5] + 0.5 * eps, trees)
    parts = []
    if self_collision:
        pairs = overlapping_pairs(tris)
        parts.append(run_driver(self_impacts, pairs, x0, x1, faces, edges, topo.own_vertices, topo.own_edges, topo.n_own_vertices, topo.n_own_edges, bx, eps)
                     .without_joined(alias))
    if len(ob0) and len(ob_faces):
        ob_topo = mesh_topology(ob_faces, ob_edges, len(ob0))
        ob_bx = mesh_boxes(ob0, ob_faces, ob_edges, eps, ob1)
        ob_tris = face_tree(ob_faces, ob_bx[4] - 0.5 * eps, ob_bx[5] + 0.5 * eps, trees)
        pairs = overlapping_pairs(tris, ob_tris)
        parts.append(run_driver(
            obstacle_impacts, pairs, x0, x1, faces, edges, topo.own_vertices, topo.own_edges, topo.n_own_vertices, topo.n_own_edges, bx, ob0, ob1, ob_faces,
            ob_edges, ob_topo.own_vertices, ob_topo.own_edges, ob_topo.n_own_vertices, ob_topo.n_own_edges, ob_bx, eps,
        ))
    return Contacts.concatenate(parts)
