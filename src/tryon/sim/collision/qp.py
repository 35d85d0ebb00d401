"""The impact-zone projection: a strictly convex QP

    min_z 1/2 (z - x)^T M (z - x)   s.t.   g_c(z) = sum_k w_ck n_c . z_k >= target  (all c)

over the free cloth vertices (M the lumped masses; pinned vertices and obstacle points
fixed), as in Harmon et al. 2008 / ARCSim's inelastic projection.

Two exact solvers:
- projected Gauss-Seidel on the dual (Hildreth 1957): coordinate ascent, cheap and quick
  when the constraints are well separated, slow when nearly parallel constraints couple;
- a primal-dual interior point method (Mehrotra 1992) on the equivalent least-distance
  problem min 1/2 |y|^2 s.t. G y >= h (y = M^1/2 (z - x), unit rows of G), whose Newton
  systems (I + G^T D G) dy = r are sparse SPD: it converges in a few dozen iterations
  whatever the conditioning. It takes over when Gauss-Seidel has not converged quickly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

from tryon.sim.geometry.primitives import jit

try:  # CHOLMOD when scikit-sparse is installed, else SciPy's SuperLU
    from sksparse.cholmod import analyze as _cholmod_analyze
except ImportError:  # pragma: no cover - depends on the environment
    _cholmod_analyze = None

PGS_SWEEPS = 60
IPM_ITERATIONS = 80
# An infeasible projection (contacts that contradict each other) shows as a primal residual
# that stops falling while the multipliers grow without bound; solvable ones here converge
# in 6-22 iterations. From IPM_STALL_START on, a primal residual above half its value
# IPM_STALL_WINDOW iterations earlier ends the solve as not converged (a sleeve's sewing
# step spent 45 s in 80-iteration solves of growing, infeasible impact zones).
IPM_STALL_START, IPM_STALL_WINDOW = 20, 10


@jit
def _constraint_rows(idx, w, n, inv_mass, x_fixed, ob, target):
    """Right-hand sides b_c = target - (fixed contributions) and diagonal dual entries
    Q_cc = sum_free w_k^2 / m_k of the constraints sum_free w_k n.z_k >= b_c."""
    c_count = idx.shape[0]
    b = np.empty(c_count)
    q = np.zeros(c_count)
    for c in range(c_count):
        fixed = 0.0
        for k in range(4):
            i = idx[c, k]
            if i >= 0 and inv_mass[i] > 0.0:
                q[c] += w[c, k] * w[c, k] * inv_mass[i]
                continue
            if i >= 0:
                p0, p1, p2 = x_fixed[i, 0], x_fixed[i, 1], x_fixed[i, 2]
            else:
                j = -i - 1
                p0, p1, p2 = ob[j, 0], ob[j, 1], ob[j, 2]
            fixed += w[c, k] * (n[c, 0] * p0 + n[c, 1] * p1 + n[c, 2] * p2)
        b[c] = target - fixed
    return b, q


@jit
def _free_value(c, idx, w, n, inv_mass, z):
    g = 0.0
    for k in range(4):
        i = idx[c, k]
        if i >= 0 and inv_mass[i] > 0.0:
            g += w[c, k] * (n[c, 0] * z[i, 0] + n[c, 1] * z[i, 1] + n[c, 2] * z[i, 2])
    return g


@jit
def _apply(c, delta, idx, w, n, inv_mass, z):
    for k in range(4):
        i = idx[c, k]
        if i >= 0 and inv_mass[i] > 0.0:
            s = delta * w[c, k] * inv_mass[i]
            z[i, 0] += s * n[c, 0]
            z[i, 1] += s * n[c, 1]
            z[i, 2] += s * n[c, 2]


@jit
def pgs_projection(x_target, inv_mass, idx, w, n, ob, target, lam0, tol, max_sweeps):
    """Mass-weighted projection of x_target onto {z : sum_k w_ck n_c.z_k >= target}, by
    projected Gauss-Seidel on the dual (Hildreth 1957), warm-started from lam0.
    Returns z, multipliers, worst violation (m), sweeps used, converged flag and each
    constraint's last correction (m) - large where Gauss-Seidel is still moving."""
    b, q = _constraint_rows(idx, w, n, inv_mass, x_target, ob, target)
    c_count = idx.shape[0]
    z = x_target.copy()
    lam = lam0.copy()
    for c in range(c_count):
        if q[c] > 0.0 and lam[c] > 0.0:
            _apply(c, lam[c], idx, w, n, inv_mass, z)
        else:
            lam[c] = 0.0
    sweeps = 0
    worst = 0.0
    converged = False
    last = np.zeros(c_count)
    for sweeps in range(1, max_sweeps + 1):
        step = 0.0
        for c in range(c_count):
            last[c] = 0.0
            if q[c] <= 0.0:
                continue
            r = b[c] - _free_value(c, idx, w, n, inv_mass, z)
            delta = max(-lam[c], r / q[c])
            if delta != 0.0:
                lam[c] += delta
                _apply(c, delta, idx, w, n, inv_mass, z)
                last[c] = abs(delta) * q[c]
                step = max(step, last[c])
        if step < 0.1 * tol:
            worst = _worst_violation(b, q, idx, w, n, inv_mass, z)
            if worst < tol:
                converged = True
                break
    worst = _worst_violation(b, q, idx, w, n, inv_mass, z)
    return z, lam, worst, sweeps, converged, last


@jit
def _worst_violation(b, q, idx, w, n, inv_mass, z):
    worst = 0.0
    for c in range(idx.shape[0]):
        r = b[c] - (_free_value(c, idx, w, n, inv_mass, z) if q[c] > 0.0 else 0.0)
        worst = max(worst, r)
    return worst


@dataclass
class QPResult:
    """Positions z [N,3], multipliers lam [C] (W (z - x) = A^T lam), worst violation (m),
    Gauss-Seidel sweeps, interior-point iterations and whether it converged."""

    z: np.ndarray
    lam: np.ndarray
    violation: float
    sweeps: int
    ipm_iterations: int
    converged: bool


def solve_projection(x, inv_mass, idx, w, n, ob, target, lam0=None, tol=1e-10) -> QPResult:
    """Mass-weighted projection of x onto the contact constraints (see the module
    docstring). Gauss-Seidel first; the impact zones (independent blocks) where it has not
    converged are then solved by the interior point method."""
    lam0 = np.zeros(len(idx)) if lam0 is None else lam0
    ob = ob if len(ob) else np.zeros((1, 3))
    z, lam, worst, sweeps, ok, last = pgs_projection(x, inv_mass, idx, w, n, ob, target, lam0, tol, PGS_SWEEPS)
    if ok:
        return QPResult(z, lam, float(worst), int(sweeps), 0, True)
    b, q = _constraint_rows(idx, w, n, inv_mass, x, ob, target)
    slack = b - _free_values(idx, w, n, inv_mass, z)
    unsettled = (q > 0) & ((last > 0.1 * tol) | (slack > tol))
    hard = _zones_of(idx, inv_mass, unsettled)
    z_h, lam_h, its, ok = ipm_projection(x, inv_mass, idx[hard], w[hard], n[hard], b[hard], tol)
    moved = np.unique(idx[hard][idx[hard] >= 0])
    z[moved] = z_h[moved]
    lam[hard] = lam_h
    worst = _worst_violation(b, q, idx, w, n, inv_mass, z)
    return QPResult(z, lam, float(worst), int(sweeps), its, bool(ok and worst < tol))


def _free_values(idx, w, n, inv_mass, z) -> np.ndarray:
    """sum over free points of w_ck n_c . z_k for every constraint [C]."""
    free = (idx >= 0) & (inv_mass[np.where(idx >= 0, idx, 0)] > 0)
    pts = z[np.where(free, idx, 0)]
    return np.einsum("ck,ckd,cd->c", np.where(free, w, 0.0), pts, n)


def _zones_of(idx, inv_mass, seeds: np.ndarray) -> np.ndarray:
    """Mask of the constraints in the same impact zone (connected through free vertices)
    as any seed constraint."""
    free = (idx >= 0) & (inv_mass[np.where(idx >= 0, idx, 0)] > 0)
    node = np.where(free, idx, -1)
    order = np.argsort(node < 0, axis=1, kind="stable")
    chain = np.take_along_axis(node, order, axis=1)  # free vertices first
    r = np.concatenate([chain[:, k] for k in range(3)])
    c = np.concatenate([chain[:, k + 1] for k in range(3)])
    ok = (r >= 0) & (c >= 0)
    size = len(inv_mass)
    graph = sp.coo_matrix((np.ones(int(ok.sum())), (r[ok], c[ok])), shape=(size, size))
    _, labels = connected_components(graph, directed=False)
    label = np.where(chain[:, 0] >= 0, labels[np.maximum(chain[:, 0], 0)], -1)
    hot = np.unique(label[seeds & (label >= 0)])
    return np.isin(label, hot)


def _constraint_matrix(idx, w, n, inv_mass):
    """Sparse A [C, 3V] over the free vertices in the constraints, and those vertices."""
    free = (idx >= 0) & (inv_mass[np.where(idx >= 0, idx, 0)] > 0)
    verts, local = np.unique(np.where(free, idx, -1), return_inverse=True)
    local = local.reshape(idx.shape)
    shift = 1 if verts[0] == -1 else 0
    verts = verts[shift:]
    c, k = np.nonzero(free)
    rows = np.repeat(c, 3)
    cols = (3 * (local[c, k] - shift)[:, None] + np.arange(3)).ravel()
    vals = (w[c, k][:, None] * n[c]).ravel()
    a = sp.csr_matrix((vals, (rows, cols)), shape=(len(idx), 3 * len(verts)))
    return a, verts


class _NewtonSolver:
    """Solves with the interior point method's SPD Newton matrices, whose sparsity does
    not change within one projection: CHOLMOD analyses the pattern once and refactors the
    values each iteration; SuperLU when
    CHOLMOD is missing or a matrix lost definiteness to round-off."""

    def __init__(self):
        self._symbolic = None

    def factor(self, m):
        a = m.tocsc()
        if _cholmod_analyze is not None:
            try:
                if self._symbolic is None:
                    self._symbolic = _cholmod_analyze(a)
                return self._symbolic.cholesky(a)
            except Exception:  # CholmodNotPositiveDefiniteError: fall through to LU
                pass
        return splu(a).solve


def ipm_projection(x, inv_mass, idx, w, n, b, tol, max_iterations=IPM_ITERATIONS):
    """Mehrotra predictor-corrector interior point method for the projection, posed as
    the least-distance problem min 1/2|y|^2 s.t. G y - s = h, s >= 0 with
    y = M^1/2 (z - x)|free and G = diag(1/|row|) A M^-1/2 (Nocedal & Wright, alg. 16.4).
    Returns z, multipliers lam (M (z - x) = A^T lam), iterations, converged."""
    a, verts = _constraint_matrix(idx, w, n, inv_mass)
    z = x.copy()
    lam = np.zeros(len(idx))
    if len(verts) == 0:
        return z, lam, 0, bool(np.all(b <= tol))
    sqrt_inv_m = np.repeat(np.sqrt(inv_mass[verts]), 3)
    g = (a @ sp.diags(sqrt_inv_m)).tocsr()
    row_norm = np.sqrt(np.asarray(g.multiply(g).sum(1)).ravel())
    has_free = row_norm > 0
    g = (sp.diags(1.0 / row_norm[has_free]) @ g[has_free]).tocsr()
    h = (b[has_free] - a[has_free] @ x[verts].ravel()) / row_norm[has_free]
    scale = max(np.abs(h).max(), 1e-300)
    h = h / scale
    y, mu_dual, its, ok = _mehrotra_ldp(g, h, tol / scale, max_iterations)
    z[verts] = x[verts] + (sqrt_inv_m * y * scale).reshape(-1, 3)
    lam[has_free] = mu_dual * scale / row_norm[has_free]
    return z, lam, its, ok


def _mehrotra_ldp(g, h, tol, max_iterations):
    """min 1/2 |y|^2 s.t. g y >= h (rows of g unit, |h| <= 1): returns y, duals, its, ok."""
    m, nv = g.shape
    gt = g.T.tocsr()
    y = np.zeros(nv)
    s = np.maximum(-h, 0.0) + 1.0
    lam = np.ones(m)
    eye = sp.identity(nv, format="csr")
    newton = _NewtonSolver()
    primal = []
    for it in range(1, max_iterations + 1):
        r_d = y - gt @ lam
        r_p = g @ y - s - h
        mu = s @ lam / m
        primal.append(np.abs(r_p).max())
        if primal[-1] < 0.01 * tol and np.abs(r_d).max() < 0.01 * tol and mu < 0.01 * tol:
            return y, lam, it, True
        if it >= IPM_STALL_START and primal[-1] >= 0.01 * tol and primal[-1] > 0.5 * primal[-1 - IPM_STALL_WINDOW]:
            return y, lam, it, False
        d = np.clip(lam / s, 1e-12, 1e12)  # bounded: keeps I + G^T D G numerically SPD
        solve = newton.factor(eye + gt @ sp.diags(d) @ g)

        def direction(r_c):
            dy = solve(-r_d - gt @ (d * r_p + r_c / s))
            dl = d * (-r_p - g @ dy) - r_c / s
            ds = (-r_c - s * dl) / lam
            return dy, dl, ds

        dy, dl, ds = direction(s * lam)  # affine-scaling predictor
        alpha = min(_step(s, ds), _step(lam, dl))
        mu_aff = (s + alpha * ds) @ (lam + alpha * dl) / m
        sigma = (mu_aff / mu) ** 3
        dy, dl, ds = direction(s * lam + ds * dl - sigma * mu)  # Mehrotra corrector
        alpha = min(1.0, 0.995 * min(_step(s, ds), _step(lam, dl)))
        y += alpha * dy
        s += alpha * ds
        lam += alpha * dl
    return y, lam, max_iterations, False


def _step(v, dv):
    """Largest step in [0, 1] keeping v + step dv >= 0."""
    neg = dv < 0
    if not neg.any():
        return 1.0
    return float(min(1.0, np.min(-v[neg] / dv[neg])))
