"""Continuous collision detection between the start and end positions of a step, every
point moving linearly (Provot 1997; Bridson, Fedkiw & Anderson 2002, sec. 4).

For each candidate pair from a BVH over swept boxes, the times when the four points are
coplanar are the roots of a cubic; the earliest candidate time at which the primitives
are also within a small distance `eps` of each other is the time of impact. Each impact
becomes a contact evaluated at that time, its normal oriented against the relative
normal motion (ARCSim's collision.cpp), i.e. towards the side the primitives started on.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tryon.sim.collision.bvh import BVH, swept_boxes, swept_point_boxes, overlapping_pairs
from tryon.errors import MeshError
from tryon.sim.collision.contacts import (
    check_thickness,
    EE_OBSTACLE,
    EE_SELF,
    FV_OBSTACLE,
    VF_OBSTACLE,
    VF_SELF,
    Contacts,
    as_points,
    check_finite,
)
from tryon.sim.collision.primitives import (
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
from tryon.sim.collision.bvh import _grow as grow
from tryon.sim.collision.proximity import grow_buffers, make_contacts, new_buffers, obstacle_id, prepare_inputs, store, vf_ids

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
def vf_ccd(pairs, xv0, xv1, xf0, xf1, faces, same, eps):
    """Earliest vertex-face impact of each candidate pair (vertex id, face id): returns
    the impacts as (pair index [M], weights [M,4], normals [M,3], gaps at toi [M], toi [M])."""
    sel, w, n_out, d_out = new_buffers(pairs.shape[0])
    toi = np.empty(sel.shape[0])
    m = 0
    ts = np.empty(8)
    for c in range(pairs.shape[0]):
        v = pairs[c, 0]
        f = pairs[c, 1]
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        if same and (v == i0 or v == i1 or v == i2):
            continue
        p0, p1 = row(xv0, v), row(xv1, v)
        a0, a1 = row(xf0, i0), row(xf1, i0)
        b0, b1 = row(xf0, i1), row(xf1, i1)
        q0, q1 = row(xf0, i2), row(xf1, i2)
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
            if abs(eval_cubic(co[0], co[1], co[2], co[3], t)) > eps * area2 * (1.0 + 1e-9) + 1e-300:
                continue  # farther than eps from the face plane: cannot be touching
            dist, u0, u1, u2 = point_triangle_distance(p, a, b, q)
            if dist >= eps or area2 <= 1e-300:
                continue
            n = scale(nn, 1.0 / area2)
            rel = sub(sub(p1, p0), combine3(u0, u1, u2, sub(a1, a0), sub(b1, b0), sub(q1, q0)))
            gap0 = dot(n, sub(p0, combine3(u0, u1, u2, a0, b0, q0)))
            sgn = _orient(n, rel, gap0)
            n = scale(n, sgn)
            if m == sel.shape[0]:
                sel, w, n_out, d_out = grow_buffers(sel, w, n_out, d_out)
                toi = grow(toi)
            store(m, c, (1.0, -u0, -u1, -u2), n, dot(n, sub(p, combine3(u0, u1, u2, a, b, q))), sel, w, n_out, d_out)
            toi[m] = t
            m += 1
            break
    return sel[:m], w[:m], n_out[:m], d_out[:m], toi[:m]


@jit
def ee_ccd(pairs, xa0, xa1, ea, xb0, xb1, eb, same, eps):
    """Earliest edge-edge impact of each candidate pair (edge id in ea, edge id in eb);
    outputs as `vf_ccd`."""
    sel, w, n_out, d_out = new_buffers(pairs.shape[0])
    toi = np.empty(sel.shape[0])
    m = 0
    ts = np.empty(8)
    for c in range(pairs.shape[0]):
        e = pairs[c, 0]
        g = pairs[c, 1]
        i0, i1 = ea[e, 0], ea[e, 1]
        j0, j1 = eb[g, 0], eb[g, 1]
        if same and (i0 == j0 or i0 == j1 or i1 == j0 or i1 == j1):
            continue
        p0, p1 = row(xa0, i0), row(xa1, i0)
        r0, r1 = row(xa0, i1), row(xa1, i1)
        q0, q1 = row(xb0, j0), row(xb1, j0)
        s0, s1 = row(xb0, j1), row(xb1, j1)
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
            if len_nn > 1e-3 * norm(sub(r, p)) * norm(sub(s, q)):
                n = scale(nn, 1.0 / len_nn)
            elif dist > 1e-300:
                n = scale(diff, 1.0 / dist)  # (nearly) parallel edges: the separation direction
            else:
                continue  # parallel and touching: the vertex-face tests of their ends apply
            ww = (1.0 - a, a, -(1.0 - b), -b)
            rel = _weighted(ww[0], ww[1], ww[2], ww[3], sub(p1, p0), sub(r1, r0), sub(q1, q0), sub(s1, s0))
            gap0 = dot(n, _weighted(ww[0], ww[1], ww[2], ww[3], p0, r0, q0, s0))
            n = scale(n, _orient(n, rel, gap0))
            if m == sel.shape[0]:
                sel, w, n_out, d_out = grow_buffers(sel, w, n_out, d_out)
                toi = grow(toi)
            store(m, c, ww, n, dot(n, diff), sel, w, n_out, d_out)
            toi[m] = t
            m += 1
            break
    return sel[:m], w[:m], n_out[:m], d_out[:m], toi[:m]


def _impacts(out: tuple, pairs: np.ndarray, ids_of, kind: int) -> Contacts:
    return make_contacts(out[:4], pairs, ids_of, kind, out[4])


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
) -> Contacts:
    """Vertex-face and edge-edge impacts while cloth moves linearly x0 -> x1 and the
    obstacle ob0 -> ob1: for every primitive pair whose swept boxes overlap, the earliest
    time t in [0, 1] at which the points are coplanar (Provot's cubic) and within `eps`
    metres of each other. Each impact is a contact with weights and normal at time t
    (`time` = t, `d` = gap at t), n oriented towards the side the primitives came from.

    `thickness` is the contact thickness h of the scene; CCD itself looks for touching
    (distance < eps, default 1e-6 m, at most h / 10), not for proximity."""
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
    margin = eps
    verts = BVH.build(*swept_point_boxes(x0, x1, margin))
    tris = BVH.build(*swept_boxes(x0, x1, faces, 0.0))
    segs = BVH.build(*swept_boxes(x0, x1, edges, 0.5 * margin))
    parts = []
    if self_collision:
        p = overlapping_pairs(verts, tris)
        out = vf_ccd(p, x0, x1, x0, x1, faces, True, eps)
        parts.append(_impacts(out, p, lambda q: vf_ids(q[:, 0], faces[q[:, 1]]), VF_SELF))
        p = overlapping_pairs(segs)
        out = ee_ccd(p, x0, x1, edges, x0, x1, edges, True, eps)
        parts.append(_impacts(out, p, lambda q: np.concatenate([edges[q[:, 0]], edges[q[:, 1]]], 1), EE_SELF))
    if len(ob0) and len(ob_faces):
        ob_tris = BVH.build(*swept_boxes(ob0, ob1, ob_faces, 0.0))
        p = overlapping_pairs(verts, ob_tris)
        out = vf_ccd(p, x0, x1, ob0, ob1, ob_faces, False, eps)
        parts.append(_impacts(out, p, lambda q: vf_ids(q[:, 0], obstacle_id(ob_faces[q[:, 1]])), VF_OBSTACLE))
        used = np.flatnonzero(np.bincount(ob_faces.ravel(), minlength=len(ob0)))
        ob_verts = BVH.build(*swept_point_boxes(ob0[used], ob1[used], margin))
        p = overlapping_pairs(ob_verts, tris)
        out = vf_ccd(p, ob0[used], ob1[used], x0, x1, faces, False, eps)
        parts.append(_impacts(out, p, lambda q: vf_ids(obstacle_id(used[q[:, 0]]), faces[q[:, 1]]), FV_OBSTACLE))
        if len(ob_edges):
            ob_segs = BVH.build(*swept_boxes(ob0, ob1, ob_edges, 0.5 * margin))
            p = overlapping_pairs(segs, ob_segs)
            out = ee_ccd(p, x0, x1, edges, ob0, ob1, ob_edges, False, eps)
            ids_of = lambda q: np.concatenate([edges[q[:, 0]], obstacle_id(ob_edges[q[:, 1]])], 1)  # noqa: E731
            parts.append(_impacts(out, p, ids_of, EE_OBSTACLE))
    return Contacts.concatenate(parts)
