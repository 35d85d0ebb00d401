"""Geometric primitives for collision handling, as numba kernels on 3-tuples.

- closest point of a triangle to a point, with barycentrics (Ericson 2005, sec. 5.1.5);
- closest points of two segments and of two lines (Ericson 2005, sec. 5.1.9);
- the coplanarity cubic of four linearly moving points and its roots in [0, 1]
  (Provot 1997; Bridson, Fedkiw & Anderson 2002, sec. 4);
- segment-triangle intersection (signed plane distances, then barycentrics).

Vectors are passed as (x, y, z) tuples so that the kernels allocate nothing.
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np
from numba import njit

# nogil: the collision drivers run on chunks of candidate pairs in threads (`parallel`)
jit = partial(njit, cache=True, error_model="numpy", nogil=True)

# barycentric tolerance of ARCSim's "inside" tests for proximity contacts
INSIDE_TOL = 1e-6
# sin^2 of the angle below which two edges count as parallel (ARCSim uses the same)
PARALLEL_SIN2 = 1e-6


@jit
def row(x: np.ndarray, i: int) -> tuple:
    return (x[i, 0], x[i, 1], x[i, 2])


@jit
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@jit
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@jit
def scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


@jit
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@jit
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@jit
def norm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@jit
def lerp(a, b, t):
    """a + t (b - a): position at time t of a point moving linearly from a to b."""
    return (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2]))


@jit
def combine3(b0, b1, b2, a, b, c):
    return (
        b0 * a[0] + b1 * b[0] + b2 * c[0],
        b0 * a[1] + b1 * b[1] + b2 * c[1],
        b0 * a[2] + b1 * b[2] + b2 * c[2],
    )


@jit
def closest_point_triangle(p, a, b, c):
    """Barycentrics (b0, b1, b2) of the point of triangle abc closest to p, found by
    Voronoi-region classification (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab = sub(b, a)
    ac = sub(c, a)
    ap = sub(p, a)
    d1 = dot(ab, ap)
    d2 = dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bp = sub(p, b)
    d3 = dot(ab, bp)
    d4 = dot(ac, bp)
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    cp = sub(p, c)
    d5 = dot(ab, cp)
    d6 = dot(ac, cp)
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return 1.0 - w, 0.0, w
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - w, w
    denom = va + vb + vc
    if denom <= 0.0:  # degenerate (zero-area) triangle: fall back to its vertex a
        return 1.0, 0.0, 0.0
    v = vb / denom
    w = vc / denom
    return 1.0 - v - w, v, w


@jit
def point_triangle_distance(p, a, b, c):
    """Unsigned distance from p to triangle abc and the barycentrics of the closest point."""
    b0, b1, b2 = closest_point_triangle(p, a, b, c)
    q = combine3(b0, b1, b2, a, b, c)
    return norm(sub(p, q)), b0, b1, b2


@jit
def plane_projection(p, a, b, c):
    """Signed distance of p to the plane of abc along the unit normal n = ab x ac / |ab x ac|
    and the (unclamped) barycentrics of p's projection; ok=False for a degenerate triangle."""
    ab = sub(b, a)
    ac = sub(c, a)
    nn = cross(ab, ac)
    area2 = norm(nn)
    if area2 <= 1e-300 or area2 * area2 <= 1e-14 * dot(ab, ab) * dot(ac, ac):
        return False, 0.0, (0.0, 0.0, 0.0), 0.0, 0.0, 0.0
    n = scale(nn, 1.0 / area2)
    ap = sub(p, a)
    h = dot(ap, n)
    # barycentrics from signed sub-areas (n is the unit normal)
    b1 = dot(cross(ap, ac), n) / area2
    b2 = dot(cross(ab, ap), n) / area2
    return True, h, n, 1.0 - b1 - b2, b1, b2


@jit
def closest_points_segments(p0, p1, q0, q1):
    """Parameters (s, t) in [0,1]^2 of the closest points p0 + s (p1-p0), q0 + t (q1-q0)
    of two segments (Ericson 5.1.9, with the degenerate cases)."""
    d1 = sub(p1, p0)
    d2 = sub(q1, q0)
    r = sub(p0, q0)
    a = dot(d1, d1)
    e = dot(d2, d2)
    f = dot(d2, r)
    if a <= 1e-300 and e <= 1e-300:
        return 0.0, 0.0
    if a <= 1e-300:
        return 0.0, min(max(f / e, 0.0), 1.0)
    c = dot(d1, r)
    if e <= 1e-300:
        return min(max(-c / a, 0.0), 1.0), 0.0
    b = dot(d1, d2)
    denom = a * e - b * b
    s = 0.0
    if denom > 1e-300:
        s = min(max((b * f - c * e) / denom, 0.0), 1.0)
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t = 1.0
        s = min(max((b - c) / a, 0.0), 1.0)
    return s, t


@jit
def segment_distance(p0, p1, q0, q1):
    """Distance between segments p0p1 and q0q1 and the closest-point parameters (s, t)."""
    s, t = closest_points_segments(p0, p1, q0, q1)
    pa = lerp(p0, p1, s)
    pb = lerp(q0, q1, t)
    return norm(sub(pa, pb)), s, t


@jit
def closest_points_lines(p0, p1, q0, q1):
    """Unclamped closest-point parameters (s, t) of the lines through p0p1 and q0q1;
    ok=False when the edges are (nearly) parallel (sin^2 angle < PARALLEL_SIN2)."""
    d1 = sub(p1, p0)
    d2 = sub(q1, q0)
    r = sub(p0, q0)
    a = dot(d1, d1)
    e = dot(d2, d2)
    b = dot(d1, d2)
    denom = a * e - b * b
    if a <= 1e-300 or e <= 1e-300 or denom <= PARALLEL_SIN2 * a * e:
        return False, 0.0, 0.0
    c = dot(d1, r)
    f = dot(d2, r)
    s = (b * f - c * e) / denom
    t = (a * f - b * c) / denom
    return True, s, t


# --------------------------------------------------------------------------- CCD cubic
@jit
def coplanarity_cubic(x1, x2, x3, v1, v2, v3):
    """Coefficients (c0, c1, c2, c3) of f(t) = (x1 + t v1) x (x2 + t v2) . (x3 + t v3):
    the scaled signed volume of four linearly moving points, relative to the first one
    (Provot 1997). f(t) = 0 when the four points are coplanar."""
    c0 = dot(cross(x1, x2), x3)
    c1 = dot(cross(v1, x2), x3) + dot(cross(x1, v2), x3) + dot(cross(x1, x2), v3)
    c2 = dot(cross(v1, v2), x3) + dot(cross(v1, x2), v3) + dot(cross(x1, v2), v3)
    c3 = dot(cross(v1, v2), v3)
    return c0, c1, c2, c3


@jit
def eval_cubic(c0, c1, c2, c3, t):
    return ((c3 * t + c2) * t + c1) * t + c0


@jit
def _quadratic_roots(a, b, c):
    """Real roots of a t^2 + b t + c (numerically stable form); returns (count, r0, r1)."""
    scale_ = max(abs(a), abs(b), abs(c))
    if scale_ == 0.0:
        return 0, 0.0, 0.0
    if abs(a) <= 1e-14 * scale_:
        if abs(b) <= 1e-14 * scale_:
            return 0, 0.0, 0.0
        return 1, -c / b, 0.0
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        return 0, 0.0, 0.0
    sq = math.sqrt(disc)
    q = -0.5 * (b + math.copysign(sq, b))
    r0 = q / a
    r1 = c / q if q != 0.0 else r0
    if r0 > r1:
        r0, r1 = r1, r0
    return 2, r0, r1


@jit
def _bisect_root(c0, c1, c2, c3, lo, hi, flo):
    """Root of the cubic in [lo, hi] where it changes sign (flo = f(lo)); bisection to
    machine precision (at most 64 halvings: robust, no Newton overshoot)."""
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        fm = eval_cubic(c0, c1, c2, c3, mid)
        if fm == 0.0:
            return mid
        if (fm < 0.0) == (flo < 0.0):
            lo = mid
            flo = fm
        else:
            hi = mid
    return 0.5 * (lo + hi)


@jit
def cubic_candidate_times(c0, c1, c2, c3, out):
    """Candidate impact times in [0, 1], ascending, written to out (length >= 7): the roots
    of the coplanarity cubic, plus the interval ends and the cubic's critical points (where
    a tangential touch or an identically-zero cubic can hide a contact). Every candidate
    is then confirmed or rejected by a distance test at that time (Bridson et al. 2002).
    Returns the number of candidates."""
    nc, r0, r1 = _quadratic_roots(3.0 * c3, 2.0 * c2, c1)
    breaks = np.empty(4)
    nb = 0
    breaks[nb] = 0.0
    nb += 1
    if nc >= 1 and 0.0 < r0 < 1.0:
        breaks[nb] = r0
        nb += 1
    if nc == 2 and 0.0 < r1 < 1.0 and r1 != r0:
        breaks[nb] = r1
        nb += 1
    breaks[nb] = 1.0
    nb += 1
    k = 0
    for i in range(nb):
        a = breaks[i]
        out[k] = a
        k += 1
        if i + 1 < nb:
            b = breaks[i + 1]
            fa = eval_cubic(c0, c1, c2, c3, a)
            fb = eval_cubic(c0, c1, c2, c3, b)
            if fa != 0.0 and fb != 0.0 and (fa < 0.0) != (fb < 0.0):
                out[k] = _bisect_root(c0, c1, c2, c3, a, b, fa)
                k += 1
    return k


# --------------------------------------------------------------------------- intersection
@jit
def segment_triangle_intersect(p, q, a, b, c, tol):
    """True when segment pq crosses triangle abc: p and q lie strictly on opposite sides of
    the plane (by more than tol, in metres) and the crossing point has barycentrics > 0."""
    ab = sub(b, a)
    ac = sub(c, a)
    nn = cross(ab, ac)
    area2 = norm(nn)
    if area2 <= 1e-300:
        return False
    n = scale(nn, 1.0 / area2)
    dp = dot(sub(p, a), n)
    dq = dot(sub(q, a), n)
    if not ((dp > tol and dq < -tol) or (dp < -tol and dq > tol)):
        return False
    s = dp / (dp - dq)
    x = lerp(p, q, s)
    ax = sub(x, a)
    b1 = dot(cross(ax, ac), n) / area2
    b2 = dot(cross(ab, ax), n) / area2
    b0 = 1.0 - b1 - b2
    return b0 > 0.0 and b1 > 0.0 and b2 > 0.0
