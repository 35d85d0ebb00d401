"""Backward pass of the impact-zone projection (Liang, Lin & Koltun 2019, sec. 4.2).

Forward (`tryon.sim.collision.qp.solve_projection`), over the free cloth vertices:

    z = argmin 1/2 (z - x)^T M (z - x)   s.t.   g_c(z) = sum_k w_ck n_c . z_k >= target

with pinned vertices and obstacle points held at their given positions. At the solution,
with the active constraints A (multiplier lambda_c > 0, g_c(z) = target) and
G = dg_A/dz, the KKT conditions are

    F1 = M (z - x) - G^T lambda = 0,     F2 = -(G z - b) = 0.

Implicit differentiation needs the adjoint (u, mu) of the symmetric KKT matrix,

    [ M   -G^T ] [u ]   [dL/dz]
    [ -G    0  ] [mu] = [  0  ],

after which every input p (x, masses, weights w, normals n, fixed points) gets
``dL/dp = -d/dp (u^T F1 + mu^T F2)``:

    dL/dx = M u,  dL/dm_i = -u_i . (z_i - x_i),
    dL/dw_ck = lambda_c n_c . u_k + mu_c n_c . z_k,  dL/dn_c = sum_k w_ck (lambda_c u_k + mu_c z_k),
    dL/dp_fixed += mu_c w_ck n_c.

QR method: with B = M^-1/2 G^T = Q R (m = active constraints), G M^-1 G^T = R^T R, so

    mu = -R^-1 Q^T y,   u = M^-1/2 (y - Q Q^T y),   y = M^-1/2 dL/dz,

one m x m triangular solve. Column-pivoted QR finds linearly dependent constraints
(|R_jj| tiny): they are dropped and their multipliers moved onto the independent ones,
G_D = E^T G_I with E = R11^-1 R12, so G^T lambda = G_I^T (lambda_I + E lambda_D). Impact
zones (constraints coupled through shared vertices) are independent blocks and are
factorised separately. The "kkt" method solves the full (n + m) system instead (sparse
LU), for the ablation of `tryon bench grad`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu
import torch

RANK_TOL = 1e-9  # |R_jj| relative to the largest below which a constraint is dependent
SLACK_TOL = 1e-8  # m: a constraint with lambda > 0 and slack below this is active


@dataclass
class BackwardStats:
    """Work of the projection backward passes: seconds, zones, and the sizes of the
    linear systems solved (QR: m x m triangular; KKT: (n + m) square)."""

    method: str = "qr"
    seconds: float = 0.0
    calls: int = 0
    zones: int = 0
    constraints: int = 0
    variables: int = 0
    system_rows: int = 0
    system_entries: int = 0
    dependent: int = 0
    per_zone: list = field(default_factory=list)

    def reset(self) -> None:
        self.seconds, self.calls, self.zones, self.constraints, self.variables = 0.0, 0, 0, 0, 0
        self.system_rows, self.system_entries, self.dependent = 0, 0, 0
        self.per_zone = []


STATS = BackwardStats()


@dataclass
class Projection:
    """One forward projection: constraint ids [C,4], its result and multipliers, the
    free-vertex mask, obstacle end positions and the target gap."""

    idx: np.ndarray
    z: np.ndarray
    lam: np.ndarray
    free: np.ndarray
    ob: np.ndarray
    target: float
    method: str = "qr"


def _zones(idx: np.ndarray, free: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected components of constraints linked by shared free vertices: (count, label [C])."""
    C = len(idx)
    cid = np.repeat(np.arange(C), 4)
    v = idx.reshape(-1)
    ok = (v >= 0) & free[np.where(v >= 0, v, 0)]
    rows = np.concatenate([cid[ok], C + v[ok]])
    cols = np.concatenate([C + v[ok], cid[ok]])
    g = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(C + n_vertices,) * 2).tocsr()
    k, labels = connected_components(g, directed=False)
    lab = labels[:C]
    uniq, lab = np.unique(lab, return_inverse=True)
    return len(uniq), lab


def _zone_matrix(idx, w, n, free, inv_sqrt_m, cons):
    """Dense B = M^-1/2 G^T [3 v, m] of one zone and its vertices."""
    sub_idx = idx[cons]
    pts = (sub_idx >= 0) & free[np.where(sub_idx >= 0, sub_idx, 0)]
    verts, local = np.unique(sub_idx[pts], return_inverse=True)
    B = np.zeros((3 * len(verts), len(cons)))
    c_of, k_of = np.nonzero(pts)
    vals = (w[cons][c_of, k_of][:, None] * n[cons][c_of]) * inv_sqrt_m[sub_idx[c_of, k_of]][:, None]
    rows = 3 * local[:, None] + np.arange(3)
    B[rows.ravel(), np.repeat(c_of, 3)] = vals.ravel()
    return B, verts


def _solve_zone_qr(B: np.ndarray, y: np.ndarray):
    """mu, projected y, independent columns, E = R11^-1 R12 via column-pivoted QR."""
    Q, R, piv = sla.qr(B, mode="economic", pivoting=True)
    diag = np.abs(np.diag(R))
    r = int(np.sum(diag > RANK_TOL * max(diag[0], 1e-300))) if len(diag) else 0
    Q1, R11 = Q[:, :r], R[:r, :r]
    qty = Q1.T @ y
    mu = -sla.solve_triangular(R11, qty)
    py = y - Q1 @ qty
    E = sla.solve_triangular(R11, R[:r, r:]) if r < B.shape[1] else np.zeros((r, 0))
    return mu, py, piv[:r], piv[r:], E, r * r


def _kkt_adjoint(G: np.ndarray, gz: np.ndarray, sqrt_m: np.ndarray) -> np.ndarray:
    """Solve [[M, -G^T], [-G, 0]] [u; mu] = [gz; 0] by sparse LU; raises
    `np.linalg.LinAlgError` when the pivots show the matrix singular (dependent rows)."""
    Gs = sp.csr_matrix(G)
    K = sp.bmat([[sp.diags(sqrt_m**2), -Gs.T], [-Gs, None]], format="csc")
    try:
        lu = splu(K)
    except RuntimeError as exc:  # exactly singular
        raise np.linalg.LinAlgError(str(exc)) from exc
    pivots = np.abs(lu.U.diagonal())
    if pivots.min() <= RANK_TOL * pivots.max():
        raise np.linalg.LinAlgError("KKT matrix is numerically singular")
    return lu.solve(np.concatenate([gz, np.zeros(G.shape[0])]))


def _solve_zone_kkt(B: np.ndarray, y: np.ndarray, sqrt_m: np.ndarray):
    """The same adjoint from the full (n + m) KKT system; when it is singular (dependent
    constraints), the independent ones are picked by a pivoted QR and it is solved again."""
    n_var, m = B.shape
    G = (B * sqrt_m[:, None]).T
    ind, dep, E = np.arange(m), np.zeros(0, np.int64), np.zeros((m, 0))
    try:
        sol = _kkt_adjoint(G, y * sqrt_m, sqrt_m)
    except np.linalg.LinAlgError:
        _, R, piv = sla.qr(B, mode="economic", pivoting=True)
        diag = np.abs(np.diag(R))
        r = int(np.sum(diag > RANK_TOL * max(diag[0], 1e-300)))
        ind, dep = piv[:r], piv[r:]
        E = sla.solve_triangular(R[:r, :r], R[:r, r:])
        sol = _kkt_adjoint(G[ind], y * sqrt_m, sqrt_m)
    u, mu = sol[:n_var], sol[n_var:]
    rows = n_var + len(ind)
    return mu, u * sqrt_m, ind, dep, E, rows * rows, rows


def projection_backward(proj: Projection, x: np.ndarray, mass: np.ndarray, w: np.ndarray, n: np.ndarray, gz: np.ndarray):
    """Gradients (dL/dx [N,3], dL/dm [N], dL/dw [C,4], dL/dn [C,3]) of the projection
    (module docstring) for the output gradient gz [N,3]."""
    tic = time.perf_counter()
    free, z, lam, idx = proj.free, proj.z, proj.lam, proj.idx
    N, C = len(x), len(idx)
    pts = np.where((idx >= 0)[..., None], z[np.where(idx >= 0, idx, 0)], proj.ob[np.where(idx < 0, -idx - 1, 0)] if len(proj.ob) else 0.0)
    gap = np.einsum("ck,ckd,cd->c", w, pts, n)
    has_free = ((idx >= 0) & free[np.where(idx >= 0, idx, 0)]).any(1)
    active = (lam > 0) & (gap - proj.target < SLACK_TOL) & has_free
    inv_sqrt_m = np.where(free, 1.0 / np.sqrt(mass), 0.0)
    u = np.where(free[:, None], gz / mass[:, None], 0.0)
    mu_all = np.zeros(C)
    lam_eff = np.zeros(C)
    cons_active = np.flatnonzero(active)
    if len(cons_active):
        n_z, labels = _zones(idx[cons_active], free, N)
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(n_z + 1))
        for zi in range(n_z):  # one dense factorisation per impact zone
            cons = cons_active[order[bounds[zi]:bounds[zi + 1]]]
            _zone_adjoint(proj, idx, w, n, free, mass, inv_sqrt_m, lam, gz, cons, u, mu_all, lam_eff)
    g_x = np.where(free[:, None], mass[:, None] * u, gz)
    g_m = np.where(free, -np.sum(u * (z - x), 1), 0.0)
    U = np.where(((idx >= 0) & free[np.where(idx >= 0, idx, 0)])[..., None], u[np.where(idx >= 0, idx, 0)], 0.0)
    un = np.einsum("ckd,cd->ck", U, n)
    zn = np.einsum("ckd,cd->ck", pts, n)
    g_w = lam_eff[:, None] * un + mu_all[:, None] * zn
    g_n = np.einsum("ck,ckd->cd", w, lam_eff[:, None, None] * U + mu_all[:, None, None] * pts)
    fixed_pt = (idx >= 0) & ~free[np.where(idx >= 0, idx, 0)]
    if fixed_pt.any():
        c_of, k_of = np.nonzero(fixed_pt)
        contrib = (mu_all[c_of] * w[c_of, k_of])[:, None] * n[c_of]
        for d in range(3):
            g_x[:, d] += np.bincount(idx[c_of, k_of], weights=contrib[:, d], minlength=N)
    STATS.seconds += time.perf_counter() - tic
    STATS.calls += 1
    return g_x, g_m, g_w, g_n


def _zone_adjoint(proj, idx, w, n, free, mass, inv_sqrt_m, lam, gz, cons, u, mu_all, lam_eff) -> None:
    """Adjoint of one impact zone (QR or full KKT), written into u, mu_all, lam_eff."""
    B, verts = _zone_matrix(idx, w, n, free, inv_sqrt_m, cons)
    sqrt_m = np.repeat(np.sqrt(mass[verts]), 3)
    y = gz[verts].reshape(-1) / sqrt_m
    if proj.method == "kkt":
        mu, py, ind, dep, E, entries, rows = _solve_zone_kkt(B, y, sqrt_m)
    else:
        mu, py, ind, dep, E, entries = _solve_zone_qr(B, y)
        rows = len(ind)
    u[verts] = (py / sqrt_m).reshape(-1, 3)
    mu_all[cons[ind]] = mu
    lam_eff[cons[ind]] = lam[cons[ind]] + (E @ lam[cons[dep]] if len(dep) else 0.0)
    STATS.zones += 1
    STATS.constraints += len(cons)
    STATS.variables += B.shape[0]
    STATS.system_rows += rows
    STATS.system_entries += entries
    STATS.dependent += len(dep)
    STATS.per_zone.append((B.shape[0], len(cons), rows, entries))


class ProjectionFn(torch.autograd.Function):
    """z = projection of x onto the constraints (w, n): forward returns the result the
    solver computed, backward is `projection_backward`."""

    @staticmethod
    def forward(ctx, x, mass, w, n, proj: Projection):
        ctx.proj = proj
        ctx.save_for_backward(x, mass, w, n)
        return torch.from_numpy(proj.z.copy())

    @staticmethod
    def backward(ctx, gz):
        x, mass, w, n = ctx.saved_tensors
        g_x, g_m, g_w, g_n = projection_backward(
            ctx.proj, x.detach().numpy(), mass.detach().numpy(), w.detach().numpy(), n.detach().numpy(), gz.detach().numpy()
        )
        return torch.from_numpy(g_x), torch.from_numpy(g_m), torch.from_numpy(g_w), torch.from_numpy(g_n), None
