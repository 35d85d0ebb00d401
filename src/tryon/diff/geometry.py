"""Contact geometry as torch functions of the positions, for the backward pass.

The collision kernels (`tryon.sim.collision`, numba) report every contact as four point
ids, weights ``w`` (summing to zero) and a unit normal ``n``; its gap is
``d = sum_k w_k n . p_k``. Which pairs touch is a discrete decision and stays fixed in the
backward pass, but ``w`` and ``n`` are smooth functions of the positions, and here they
are recomputed as torch expressions so that gradients see how they move:

* vertex-face (point ``p`` against triangle ``abc``)::

      n = s (b - a) x (c - a) / |(b - a) x (c - a)|,   w = (1, -b0, -b1, -b2)

  with ``b`` the barycentrics of ``p``'s projection on the plane and ``s = +-1`` the
  orientation the kernel chose;
* edge-edge (``p0 p1`` against ``q0 q1``): ``(s, t)`` the closest points of the two lines
  (Ericson 5.1.9), clamped to the segments, ``w = (1 - s, s, -(1 - t), -t)`` and
  ``n = +-(p1 - p0) x (q1 - q0) / |...|``;
* impacts from continuous collision detection are evaluated at the time of impact ``t*``,
  a root of Provot's coplanarity cubic
  ``c(t) = (P1(t) - P0(t)) x (P2(t) - P0(t)) . (P3(t) - P0(t))``, ``P(t) = (1 - t) X0 + t X1``;
  its derivative follows from implicit differentiation, ``dt* = -dc / c'(t*)``.

Each recomputed quantity is checked against the kernel's value; where they disagree (a
clamped closest point, a special-case normal of a grazing edge pair, a time of impact at
the end of the step) the kernel's value is used as a constant.
"""

from __future__ import annotations

import numpy as np
import torch

from tryon.sim.collision import EE_OBSTACLE, EE_SELF, Contacts

NORMAL_MATCH = 1.0 - 1e-8  # |cos| between recomputed and reported normals
WEIGHT_MATCH = 1e-6  # largest weight difference accepted as the same closest point
ROOT_MATCH = 1e-9  # |c(t*) / c'(t*)| (time units) below which t* is a root of the cubic


def triple(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Scalar triple product ``(a x b) . c`` over the last axis."""
    return (torch.linalg.cross(a, b, dim=-1) * c).sum(-1)


def gather_points(idx: np.ndarray, x: torch.Tensor, ob: torch.Tensor | np.ndarray) -> torch.Tensor:
    """Positions ``[C, 4, 3]`` of the contact points: cloth rows of ``x`` (ids >= 0) and
    obstacle rows of ``ob`` (ids ``-i - 1``)."""
    idx_t = torch.as_tensor(idx, dtype=torch.int64)
    cloth = idx_t >= 0
    pts = x[idx_t.clamp_min(0)]
    ob_t = torch.as_tensor(ob, dtype=x.dtype)
    if bool((~cloth).any()):
        pts = torch.where(cloth[..., None], pts, ob_t[(-idx_t - 1).clamp_min(0)])
    return pts


def vf_frame(P: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit face normal ``[C, 3]`` and weights ``(1, -b0, -b1, -b2)`` ``[C, 4]`` of vertex
    ``P[:, 0]`` against triangle ``P[:, 1:]`` (unclamped projection barycentrics)."""
    p, a, b, c = P.unbind(1)
    ab, ac, ap = b - a, c - a, p - a
    nn = torch.linalg.cross(ab, ac, dim=-1)
    area2 = nn.norm(dim=-1).clamp_min(1e-300)
    n = nn / area2[:, None]
    b1 = (torch.linalg.cross(ap, ac, dim=-1) * n).sum(-1) / area2
    b2 = (torch.linalg.cross(ab, ap, dim=-1) * n).sum(-1) / area2
    b0 = 1.0 - b1 - b2
    return n, torch.stack([torch.ones_like(b0), -b0, -b1, -b2], 1)


def ee_frame(P: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Unit normal of the two edge directions ``[C, 3]``, weights ``[C, 4]`` of the closest
    points of the lines clamped to the segments, and the closest-point parameters s, t."""
    p0, p1, q0, q1 = P.unbind(1)
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, b = (d1 * d1).sum(-1), (d2 * d2).sum(-1), (d1 * d2).sum(-1)
    c, f = (d1 * r).sum(-1), (d2 * r).sum(-1)
    den = (a * e - b * b).clamp_min(1e-300)
    s = ((b * f - c * e) / den).clamp(0.0, 1.0)
    t = ((a * f - b * c) / den).clamp(0.0, 1.0)
    nn = torch.linalg.cross(d1, d2, dim=-1)
    n = nn / nn.norm(dim=-1).clamp_min(1e-300)[:, None]
    w = torch.stack([1.0 - s, s, -(1.0 - t), -t], 1)
    return n, w, s, t


def _unit(v: torch.Tensor) -> torch.Tensor:
    return v / v.norm(dim=-1).clamp_min(1e-300)[:, None]


def _oriented(candidates: list[torch.Tensor], n_ref: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The first candidate normal parallel to the reported one, with its sign; and a mask
    of the contacts where one matched."""
    out = n_ref.clone()
    done = torch.zeros(len(n_ref), dtype=torch.bool)
    for cand in candidates:
        cos = (cand.detach() * n_ref).sum(-1)
        ok = (cos.abs() > NORMAL_MATCH) & ~done
        sign = torch.where(cos < 0, -1.0, 1.0).to(cand.dtype)
        out = torch.where(ok[:, None], sign[:, None] * cand, out)
        done = done | ok
    return out, done


def contact_frame(
    P: torch.Tensor, kind: np.ndarray, n_ref: np.ndarray, w_ref: np.ndarray, P0: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Weights ``[C, 4]`` and oriented normals ``[C, 3]`` as torch functions of the contact
    point positions ``P [C, 4, 3]`` (at the time of impact for impacts, whose start
    positions ``P0`` give the extra normal candidate of grazing edge pairs). Values the
    recomputation does not reproduce fall back to the reported constants."""
    n_ref_t = torch.as_tensor(n_ref, dtype=P.dtype)
    w_ref_t = torch.as_tensor(w_ref, dtype=P.dtype)
    if len(P) == 0:
        return w_ref_t, n_ref_t
    is_ee = torch.as_tensor(np.isin(kind, (EE_SELF, EE_OBSTACLE)))
    n_vf, w_vf = vf_frame(P)
    n_ee, w_ee, s, t = ee_frame(P)
    w = torch.where(is_ee[:, None], w_ee, w_vf)
    n_main = torch.where(is_ee[:, None], n_ee, n_vf)
    candidates = [n_main]
    if P0 is not None:  # ccd.ee_impact: separation direction at the impact, then at the start
        p0, p1, q0, q1 = P.unbind(1)
        diff = p0 + s[:, None] * (p1 - p0) - (q0 + t[:, None] * (q1 - q0))
        s0, r0, u0, v0 = P0.unbind(1)
        diff0 = s0 + s[:, None] * (r0 - s0) - (u0 + t[:, None] * (v0 - u0))
        ee_only = is_ee[:, None]
        candidates += [torch.where(ee_only, _unit(diff), n_main), torch.where(ee_only, _unit(diff0), n_main)]
    n, _ = _oriented(candidates, n_ref_t)
    w_ok = (w.detach() - w_ref_t).abs().amax(1) < WEIGHT_MATCH
    w = torch.where(w_ok[:, None], w, w_ref_t)
    return w, n


def impact_time(X0: torch.Tensor, X1: torch.Tensor, t_ref: np.ndarray) -> torch.Tensor:
    """Time of impact ``[C]`` with its implicit derivative: ``t* - (c(t*) - c(t*)|const) / c'(t*)``
    for the roots of the coplanarity cubic strictly inside the step; other candidate
    times (interval ends, tangential touches) are constants."""
    t0 = torch.as_tensor(t_ref, dtype=X0.dtype)
    if len(t0) == 0:
        return t0
    tt = t0[:, None, None]
    P = X0 + tt * (X1 - X0)
    V = (X1 - X0).detach()
    e = [P[:, k] - P[:, 0] for k in (1, 2, 3)]
    de = [V[:, k] - V[:, 0] for k in (1, 2, 3)]
    c = triple(*e)
    ed = [q.detach() for q in e]
    dc = triple(de[0], ed[1], ed[2]) + triple(ed[0], de[1], ed[2]) + triple(ed[0], ed[1], de[2])
    safe = dc.abs() > 1e-300
    newton = torch.where(safe, c.detach() / torch.where(safe, dc, torch.ones_like(dc)), torch.full_like(dc, np.inf))
    root = (t0 > 0.0) & (t0 < 1.0) & (newton.abs() < ROOT_MATCH)
    shift = (c - c.detach()) / torch.where(root, dc, torch.ones_like(dc))
    return torch.where(root, t0 - shift, t0)


def impact_frame(
    constraints: Contacts, x0: torch.Tensor, x1: torch.Tensor, ob0: np.ndarray, ob1: np.ndarray
) -> tuple[torch.Tensor, torch.Tensor]:
    """Weights and normals of impacts found between cloth positions ``x0 -> x1`` (torch)
    and obstacle positions ``ob0 -> ob1`` (constants), at their time of impact."""
    X0 = gather_points(constraints.idx, x0, ob0)
    X1 = gather_points(constraints.idx, x1, ob1)
    t = impact_time(X0, X1, constraints.time)[:, None, None]
    P = X0 + t * (X1 - X0)
    return contact_frame(P, constraints.kind, constraints.n, constraints.w, P0=X0)
