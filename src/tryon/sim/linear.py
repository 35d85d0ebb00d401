"""Sparse assembly of the implicit-Euler system and its solvers.

The system matrix has one 3x3 block per pair of vertices that share a triangle or a
bending hinge. Its sparsity pattern is fixed for a mesh, so it is built once
(`BlockPattern`), element Hessians are scattered into it by a compiled kernel, and the
Cholesky analysis (CHOLMOD, when scikit-sparse is installed) is reused every step.
Solvers: CHOLMOD supernodal Cholesky, SciPy SuperLU, or a preconditioned conjugate
gradient with Baraff-Witkin constraint filtering (compiled, on numba's threads, with the
same result on any thread count). The conjugate gradient's preconditioner is block-Jacobi
(`pcg`) or two-level (`pcg-two-level`, what `auto` picks from 1,500 vertices when CHOLMOD
is installed): block-Jacobi plus a coarse correction on aggregates of neighbouring
vertices (`CoarseSpace`), which keeps the iteration count from growing with the mesh's
resolution.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

import numba as nb
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tryon.errors import SimulationError

try:  # CHOLMOD is optional: it needs SuiteSparse from the system (see the Makefile).
    from sksparse.cholmod import CholmodError as _CholmodError
    from sksparse.cholmod import analyze as _cholmod_analyze

    HAVE_CHOLMOD = True
except ImportError:  # pragma: no cover - depends on the machine
    HAVE_CHOLMOD = False


class BlockPattern:
    """Block sparsity of a vertex-coupled 3N x 3N symmetric matrix.

    `elements` is a list of [E_k, n_k] vertex-index arrays (faces, hinges); every pair of
    vertices inside an element, and every vertex with itself, gets a block.
    """

    def __init__(self, num_vertices: int, elements: list[np.ndarray]):
        n = num_vertices
        rows = [np.arange(n)]
        cols = [np.arange(n)]
        for el in elements:
            k = el.shape[1]
            a = np.repeat(np.arange(k), k)
            b = np.tile(np.arange(k), k)
            rows.append(el[:, a].ravel())
            cols.append(el[:, b].ravel())
        r = np.concatenate(rows).astype(np.int64)
        c = np.concatenate(cols).astype(np.int64)
        key = np.unique(r * n + c)
        self.n = n
        self.block_row = key // n
        self.block_col = key % n
        self.indptr = np.searchsorted(self.block_row, np.arange(n + 1)).astype(np.int64)
        self.indices = self.block_col.copy()
        self.nblocks = len(key)
        self._key = key
        self.diag_block = self.block_index(np.arange(n), np.arange(n))
        self.element_maps = [self._element_map(el) for el in elements]
        self._csc_perm, self._csc_indptr, self._csc_indices = self._scalar_csc()

    def block_index(self, r: np.ndarray, c: np.ndarray) -> np.ndarray:
        key = np.asarray(r, np.int64) * self.n + np.asarray(c, np.int64)
        pos = np.searchsorted(self._key, key)
        if np.any(pos >= len(self._key)) or np.any(self._key[np.minimum(pos, len(self._key) - 1)] != key):
            raise ValueError("block outside the sparsity pattern")
        return pos

    def _element_map(self, el: np.ndarray) -> np.ndarray:
        k = el.shape[1]
        a = np.repeat(np.arange(k), k)
        b = np.tile(np.arange(k), k)
        return self.block_index(el[:, a].ravel(), el[:, b].ravel()).reshape(len(el), k * k)

    def _scalar_csc(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Permutation from flattened blocks [nb,3,3] to the data of a scalar CSC matrix."""
        br, bc = self.block_row, self.block_col
        rr = (3 * br[:, None, None] + np.arange(3)[None, :, None]).repeat(3, 2).ravel()
        cc = (3 * bc[:, None, None] + np.arange(3)[None, None, :]).repeat(3, 1).ravel()
        order = np.lexsort((rr, cc))
        indices = rr[order]
        indptr = np.searchsorted(cc[order], np.arange(3 * self.n + 1))
        return order, indptr.astype(np.int64), indices.astype(np.int64)

    def zeros(self) -> np.ndarray:
        return np.zeros((self.nblocks, 3, 3))

    def to_csc(self, blocks: np.ndarray) -> sp.csc_matrix:
        data = blocks.reshape(-1)[self._csc_perm]
        return sp.csc_matrix((data, self._csc_indices, self._csc_indptr), shape=(3 * self.n, 3 * self.n))


@nb.njit(cache=True)
def scatter_element_blocks(blocks, element_map, hess, k):
    """blocks[map[e, a*k+b]] += hess[e, 3a:3a+3, 3b:3b+3] for every element e."""
    for e in range(hess.shape[0]):
        for a in range(k):
            for b in range(k):
                dst = element_map[e, a * k + b]
                for i in range(3):
                    for j in range(3):
                        blocks[dst, i, j] += hess[e, 3 * a + i, 3 * b + j]


@nb.njit(cache=True)
def scatter_rank_one_blocks(blocks, element_map, coeff, u, k):
    """`scatter_element_blocks` of the Hessians coeff[e] u[e] u[e]^T, without writing them:
    entry (m, n) is (coeff u[min(m, n)]) u[max(m, n)], the very number (and order of
    additions) of the written Hessian (`tryon.sim.forces.bending`)."""
    for e in range(u.shape[0]):
        c = coeff[e]
        for a in range(k):
            for b in range(k):
                dst = element_map[e, a * k + b]
                for i in range(3):
                    m = 3 * a + i
                    for j in range(3):
                        n = 3 * b + j
                        if m <= n:
                            blocks[dst, i, j] += (c * u[e, m]) * u[e, n]
                        else:
                            blocks[dst, i, j] += (c * u[e, n]) * u[e, m]


@nb.njit(cache=True)
def add_diagonal_blocks(blocks, diag_block, vertices, block_values):
    for q in range(vertices.shape[0]):
        dst = diag_block[vertices[q]]
        for i in range(3):
            for j in range(3):
                blocks[dst, i, j] += block_values[q, i, j]


@nb.njit(cache=True, inline="always")
def _block_row(indptr, indices, blocks, x, r, out):
    """out[r] = (block row r of the matrix) . x. Inlined: a call per row costs 40 % in the PCG."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for q in range(indptr[r], indptr[r + 1]):
        k = indices[q]
        x0 = x[k, 0]
        x1 = x[k, 1]
        x2 = x[k, 2]
        s0 += blocks[q, 0, 0] * x0 + blocks[q, 0, 1] * x1 + blocks[q, 0, 2] * x2
        s1 += blocks[q, 1, 0] * x0 + blocks[q, 1, 1] * x1 + blocks[q, 1, 2] * x2
        s2 += blocks[q, 2, 0] * x0 + blocks[q, 2, 1] * x1 + blocks[q, 2, 2] * x2
    out[r, 0] = s0
    out[r, 1] = s1
    out[r, 2] = s2


@nb.njit(cache=True)
def bsr_matvec(indptr, indices, blocks, x, out):
    for r in range(indptr.shape[0] - 1):
        _block_row(indptr, indices, blocks, x, r, out)


PCG_CHUNK = 256  # rows per chunk of the solver's loops (default); partial sums are joined in chunk order


@nb.njit(cache=True)
def _join(partial):
    """Sum of per-chunk partial sums in chunk order: the same on any number of threads."""
    s = 0.0
    for c in range(partial.shape[0]):
        s += partial[c]
    return s


@nb.njit(parallel=True, cache=True)
def _inverse_diagonal(blocks, diag_block):
    n = diag_block.shape[0]
    pinv = np.zeros((n, 3, 3))
    for i in nb.prange(n):
        pinv[i] = np.linalg.inv(blocks[diag_block[i]])
    return pinv


@nb.njit(parallel=True, cache=True)
def _filtered_matvec(indptr, indices, blocks, p, free, ap, partial, chunk):
    """ap = A p on free rows (0 elsewhere); partial[c] = chunk c's share of p . ap."""
    n = p.shape[0]
    for c in nb.prange(partial.shape[0]):
        s = 0.0
        for r in range(c * chunk, min(n, (c + 1) * chunk)):
            if not free[r]:
                ap[r, 0] = 0.0
                ap[r, 1] = 0.0
                ap[r, 2] = 0.0
                continue
            _block_row(indptr, indices, blocks, p, r, ap)
            s += p[r, 0] * ap[r, 0] + p[r, 1] * ap[r, 1] + p[r, 2] * ap[r, 2]
        partial[c] = s


@nb.njit(cache=True, inline="always")
def _step_row(alpha, p, ap, x, r, i):
    """x[i] += alpha p[i], r[i] -= alpha ap[i]."""
    for a in range(3):
        x[i, a] += alpha * p[i, a]
        r[i, a] -= alpha * ap[i, a]


@nb.njit(cache=True, inline="always")
def _precondition_row(pinv, r, z, i, e0, e1, e2, rz, rr):
    """z[i] = pinv[i] r[i] + e, with e the coarse correction (-0.0 for block-Jacobi: adding
    it changes no bit); returns rz + r[i] . z[i] and rr + r[i] . r[i], added term by term."""
    for a in range(3):
        e = e0 if a == 0 else (e1 if a == 1 else e2)
        z[i, a] = pinv[i, a, 0] * r[i, 0] + pinv[i, a, 1] * r[i, 1] + pinv[i, a, 2] * r[i, 2] + e
        rz += r[i, a] * z[i, a]
        rr += r[i, a] * r[i, a]
    return rz, rr


@nb.njit(parallel=True, cache=True)
def _update_and_precondition(alpha, p, ap, pinv, free, x, r, z, rz_part, rr_part, chunk):
    """x += alpha p, r -= alpha ap, z = P^-1 r on free rows; per-chunk r . z and r . r.
    Only p and ap may be the same array (numba compiles the kernel assuming that no array
    it writes shares memory with another argument)."""
    n = p.shape[0]
    for c in nb.prange(rz_part.shape[0]):
        rz = 0.0
        rr = 0.0
        for i in range(c * chunk, min(n, (c + 1) * chunk)):
            _step_row(alpha, p, ap, x, r, i)
            if free[i]:
                rz, rr = _precondition_row(pinv, r, z, i, -0.0, -0.0, -0.0, rz, rr)
            else:
                z[i, 0] = 0.0
                z[i, 1] = 0.0
                z[i, 2] = 0.0
        rz_part[c] = rz
        rr_part[c] = rr


@nb.njit(parallel=True, cache=True)
def _next_direction(beta, z, p, chunk):
    n = p.shape[0]
    for c in nb.prange((n + chunk - 1) // chunk):
        for i in range(c * chunk, min(n, (c + 1) * chunk)):
            for a in range(3):
                p[i, a] = z[i, a] + beta * p[i, a]


@nb.njit(cache=True)
def _initial_residual(indptr, indices, blocks, b, x, free):
    """(r = b - A x on free rows, 0 elsewhere; |b| on free rows, 1 when that is 0)."""
    n = b.shape[0]
    ax = np.zeros((n, 3))
    bsr_matvec(indptr, indices, blocks, x, ax)
    r = np.zeros((n, 3))
    bnorm = 0.0
    for i in range(n):
        if free[i]:
            for a in range(3):
                r[i, a] = b[i, a] - ax[i, a]
                bnorm += b[i, a] * b[i, a]
    bnorm = np.sqrt(bnorm)
    if bnorm == 0.0:
        bnorm = 1.0
    return r, bnorm


@nb.njit(cache=True)
def filtered_pcg(indptr, indices, blocks, diag_block, b, x, free, tol, max_iter, chunk=PCG_CHUNK):
    """Baraff-Witkin modified PCG: solves A x = b on the free vertices, keeping the given
    values of x on constrained (not free) vertices. Block-Jacobi preconditioner.
    Returns the iteration count; convergence when |r| <= tol * |b_free|.

    Its loops run on numba's threads over fixed chunks of rows, and every dot product
    joins the chunks' partial sums in order, so the iterates are bit-identical on 1 thread
    and on many (for a given `chunk`, rows per chunk)."""
    n = b.shape[0]
    chunks = (n + chunk - 1) // chunk
    pinv = _inverse_diagonal(blocks, diag_block)
    part_a = np.zeros(chunks)
    part_b = np.zeros(chunks)
    r, bnorm = _initial_residual(indptr, indices, blocks, b, x, free)
    z = np.zeros((n, 3))
    ap = np.zeros((n, 3))
    # alpha = 0 leaves x and r as they are and computes z = P^-1 r with r . z and r . r
    _update_and_precondition(0.0, ap, ap, pinv, free, x, r, z, part_a, part_b, chunk)
    rz = _join(part_a)
    rr = _join(part_b)
    p = z.copy()
    it = 0
    while it < max_iter:
        if np.sqrt(rr) <= tol * bnorm:
            break
        _filtered_matvec(indptr, indices, blocks, p, free, ap, part_a, chunk)
        alpha = rz / _join(part_a)
        _update_and_precondition(alpha, p, ap, pinv, free, x, r, z, part_a, part_b, chunk)
        rz_new = _join(part_a)
        rr = _join(part_b)
        beta = rz_new / rz
        rz = rz_new
        _next_direction(beta, z, p, chunk)
        it += 1
    return it


# ---------------------------------------------------------------- two-level preconditioner
AGGREGATE_RADIUS = 2  # an aggregate: a vertex and the vertices up to this many edges away (10-16 on a mesh)


@nb.njit(cache=True)
def aggregate_vertices(indptr, indices, radius):
    """Aggregate index [N] of every vertex: in vertex order, each vertex not yet taken
    starts an aggregate of the untaken vertices within `radius` steps of the block graph;
    an aggregate of one vertex then joins a neighbouring one. Labels are 0..count-1."""
    n = indptr.shape[0] - 1
    agg = -np.ones(n, np.int64)
    frontier = np.empty(n, np.int64)
    nxt = np.empty(n, np.int64)
    count = 0
    for s in range(n):
        if agg[s] >= 0:
            continue
        agg[s] = count
        frontier[0] = s
        nf = 1
        for _ in range(radius):
            nn = 0
            for f in range(nf):
                v = frontier[f]
                for q in range(indptr[v], indptr[v + 1]):
                    u = indices[q]
                    if agg[u] < 0:
                        agg[u] = count
                        nxt[nn] = u
                        nn += 1
            frontier[:nn] = nxt[:nn]
            nf = nn
        count += 1
    size = np.zeros(count, np.int64)
    for v in range(n):
        size[agg[v]] += 1
    for v in range(n):
        if size[agg[v]] == 1:
            for q in range(indptr[v], indptr[v + 1]):
                u = indices[q]
                if agg[u] != agg[v]:
                    size[agg[v]] -= 1
                    agg[v] = agg[u]
                    size[agg[u]] += 1
                    break
    label = -np.ones(count, np.int64)
    used = 0
    for v in range(n):
        if label[agg[v]] < 0:
            label[agg[v]] = used
            used += 1
        agg[v] = label[agg[v]]
    return agg


@nb.njit(cache=True)
def _galerkin_blocks(blocks, block_row, block_col, free, fine_to_coarse, coarse):
    """coarse = P^T A P for the piecewise-constant prolongation P on free vertices: each
    block between free vertices adds into the block between their aggregates."""
    coarse[:] = 0.0
    for q in range(blocks.shape[0]):
        if free[block_row[q]] and free[block_col[q]]:
            dst = fine_to_coarse[q]
            for i in range(3):
                for j in range(3):
                    coarse[dst, i, j] += blocks[q, i, j]


@nb.njit(parallel=True, cache=True)
def _restrict(r, free, members, member_ptr, rc):
    """rc[a] = sum of r over the free vertices of aggregate a (P^T r)."""
    for a in nb.prange(member_ptr.shape[0] - 1):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for q in range(member_ptr[a], member_ptr[a + 1]):
            i = members[q]
            if free[i]:
                s0 += r[i, 0]
                s1 += r[i, 1]
                s2 += r[i, 2]
        rc[a, 0] = s0
        rc[a, 1] = s1
        rc[a, 2] = s2


@nb.njit(parallel=True, cache=True)
def _jacobi_plus_coarse(pinv, r, ec, aggregate, free, z, rz_part, chunk):
    """z = D^-1 r + P ec on free rows (0 elsewhere); per-chunk r . z."""
    n = r.shape[0]
    for c in nb.prange(rz_part.shape[0]):
        rz = 0.0
        for i in range(c * chunk, min(n, (c + 1) * chunk)):
            if free[i]:
                g = aggregate[i]
                rz = _precondition_row(pinv, r, z, i, ec[g, 0], ec[g, 1], ec[g, 2], rz, 0.0)[0]
            else:
                z[i, 0] = 0.0
                z[i, 1] = 0.0
                z[i, 2] = 0.0
        rz_part[c] = rz


@nb.njit(parallel=True, cache=True)
def _update_iterate(alpha, p, ap, free, x, r, rr_part, chunk):
    """x += alpha p, r -= alpha ap; per-chunk r . r over free rows."""
    n = p.shape[0]
    for c in nb.prange(rr_part.shape[0]):
        rr = 0.0
        for i in range(c * chunk, min(n, (c + 1) * chunk)):
            _step_row(alpha, p, ap, x, r, i)
            if free[i]:
                rr += r[i, 0] * r[i, 0] + r[i, 1] * r[i, 1] + r[i, 2] * r[i, 2]
        rr_part[c] = rr


_NEEDS_CHOLMOD = ("linear solver '{kind}' needs CHOLMOD: scikit-sparse (pip install 'tryon[cholmod]' with "
                  "libsuitesparse-dev installed); use 'pcg' or 'splu' instead")


class CoarseSolveError(SimulationError):
    """The coarse matrix is not positive definite (a pivot of its LDL' not positive)."""


class CoarseSpace:
    """Aggregates of neighbouring vertices, one translation (3 unknowns) each: the coarse
    space of the two-level preconditioner M^-1 = D^-1 + P (P^T A P)^-1 P^T (additive
    two-level Schwarz with unsmoothed aggregation). Block-Jacobi (D^-1) removes the
    error that changes from vertex to vertex, the coarse solve the smooth error that
    block-Jacobi needs hundreds of iterations for: on a 128x128 cloth the conjugate
    gradient needs about 56 iterations instead of 400 (docs/ENGINE.md).

    Built once per sparsity pattern; `factorize` assembles and factorises the coarse
    matrix of one system (CHOLMOD's simplicial LDL', its analysis reused), which uses no
    threads: the result is the same on any thread count. The coarse solves run between
    the compiled kernels of each iteration; solving CHOLMOD's factors in compiled code
    instead was slower (docs/ENGINE.md)."""

    def __init__(self, pattern: BlockPattern, radius: int = AGGREGATE_RADIUS):
        if not HAVE_CHOLMOD:
            raise SimulationError(_NEEDS_CHOLMOD.format(kind="pcg-two-level"))
        self.aggregate = aggregate_vertices(pattern.indptr, pattern.indices, radius)
        self.count = int(self.aggregate.max()) + 1
        self.members = np.argsort(self.aggregate, kind="stable").astype(np.int64)
        self.member_ptr = np.searchsorted(self.aggregate[self.members], np.arange(self.count + 1)).astype(np.int64)
        row, col = self.aggregate[pattern.block_row], self.aggregate[pattern.block_col]
        self.pattern = BlockPattern(self.count, [np.unique(np.stack([row, col], 1), axis=0)])
        self.fine_to_coarse = self.pattern.block_index(row, col)
        self._fine = pattern
        self._blocks = self.pattern.zeros()
        self._analysis = None

    def factorize(self, blocks: np.ndarray, free: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
        """The coarse solve for this system: rc [count*3] -> ec [count*3]."""
        fine = self._fine
        _galerkin_blocks(blocks, fine.block_row, fine.block_col, free, self.fine_to_coarse, self._blocks)
        empty = np.bincount(self.aggregate[free], minlength=self.count) == 0  # every vertex pinned
        self._blocks[self.pattern.diag_block[empty]] = np.eye(3)
        A = self.pattern.to_csc(self._blocks)
        if self._analysis is None:
            self._analysis = _cholmod_analyze(A, mode="simplicial")
        try:
            self._analysis.cholesky_inplace(A)
        except _CholmodError as exc:
            raise CoarseSolveError(f"coarse matrix not positive definite: {exc}") from exc
        pivots = self._analysis.D()  # LDL' factorises indefinite matrices too: CG needs D > 0
        if not np.all(pivots > 0.0):
            raise CoarseSolveError(f"coarse matrix not positive definite (smallest pivot {pivots.min():.3g})")
        return self._analysis


@nb.njit(cache=True)
def _two_level_descend(indptr, indices, blocks, p, ap, free, x, r, rz, members, member_ptr, rc, part, chunk):
    """One step along p (x += alpha p, r -= alpha A p) and the new residual restricted to
    the aggregates (rc); returns r . r. One compiled call: the loop runs in Python."""
    _filtered_matvec(indptr, indices, blocks, p, free, ap, part, chunk)
    alpha = rz / _join(part)
    _update_iterate(alpha, p, ap, free, x, r, part, chunk)
    rr = _join(part)
    _restrict(r, free, members, member_ptr, rc)
    return rr


@nb.njit(cache=True)
def _two_level_direction(pinv, r, ec, aggregate, free, z, p, rz, part, chunk, first):
    """z = D^-1 r + P ec, then the next direction p (p = z on the first); returns r . z."""
    _jacobi_plus_coarse(pinv, r, ec, aggregate, free, z, part, chunk)
    rz_new = _join(part)
    _next_direction(0.0 if first else rz_new / rz, z, p, chunk)
    return rz_new


def two_level_pcg(pattern: BlockPattern, coarse: CoarseSpace, blocks: np.ndarray, b: np.ndarray, x: np.ndarray,
                  free: np.ndarray, tol: float, max_iter: int, chunk: int = PCG_CHUNK) -> int:
    """`filtered_pcg` with the two-level preconditioner of `coarse`: x updated in place,
    the iteration count returned (the same convergence test). Raises CoarseSolveError,
    before touching x, when the coarse matrix cannot be factorised."""
    n = b.shape[0]
    part = np.zeros((n + chunk - 1) // chunk)
    r, bnorm = _initial_residual(pattern.indptr, pattern.indices, blocks, b, x, free)
    z, p, ap = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    _update_iterate(0.0, ap, ap, free, x, r, part, chunk)  # alpha = 0: r . r only
    if np.sqrt(_join(part)) <= tol * bnorm:  # the warm start solves it already
        return 0
    solve_coarse = coarse.factorize(blocks, free)
    pinv = _inverse_diagonal(blocks, pattern.diag_block)
    rc = np.zeros((coarse.count, 3))
    _restrict(r, free, coarse.members, coarse.member_ptr, rc)
    rz, it = 0.0, 0
    while True:
        ec = np.asarray(solve_coarse(rc.reshape(-1))).reshape(-1, 3)
        rz = _two_level_direction(pinv, r, ec, coarse.aggregate, free, z, p, rz, part, chunk, it == 0)
        rr = _two_level_descend(pattern.indptr, pattern.indices, blocks, p, ap, free, x, r, rz, coarse.members,
                                coarse.member_ptr, rc, part, chunk)
        it += 1
        if np.sqrt(rr) <= tol * bnorm or it >= max_iter:
            return it


def reduced_system(pattern: BlockPattern, blocks: np.ndarray, rhs: np.ndarray, fixed: np.ndarray,
                   fixed_values: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    """The system with the fixed vertices' values moved to the right-hand side and their
    rows and columns replaced by identity: (A as CSC, b [N,3])."""
    b = rhs.copy()
    if fixed.any():
        x_fixed = np.zeros_like(rhs)
        x_fixed[fixed] = fixed_values
        ax = np.zeros_like(rhs)
        bsr_matvec(pattern.indptr, pattern.indices, blocks, x_fixed, ax)
        b -= ax
        blocks = blocks.copy()
        blocks[fixed[pattern.block_row] | fixed[pattern.block_col]] = 0.0
        blocks[pattern.diag_block[fixed]] = np.eye(3)
        b[fixed] = fixed_values
    return pattern.to_csc(blocks), b


SOLVER_KINDS = ("auto", "pcg-two-level", "pcg", "cholmod", "splu")
TWO_LEVEL_MIN_VERTICES = 1500  # below it, block-Jacobi alone is as fast (tryon bench sim at 32x32)
_AUTO_KIND: ContextVar[str | None] = ContextVar("tryon_auto_linear_solver", default=None)


@contextmanager
def auto_solver_pinned(kind: str) -> Iterator[None]:
    """Within the block, solvers asked for 'auto' use `kind`. Dataset generation pins
    the solver its samples were made with, so that a dataset grown over many runs holds
    one solver's samples (`tryon.dataset.generate`)."""
    if kind not in SOLVER_KINDS or kind == "auto":
        raise SimulationError(f"cannot pin linear solver {kind!r}; use one of {', '.join(SOLVER_KINDS[1:])}")
    token = _AUTO_KIND.set(kind)
    try:
        yield
    finally:
        _AUTO_KIND.reset(token)


def resolve_kind(kind: str, num_vertices: int) -> str:
    """What 'auto' means for a system of this size (or the pinned kind)."""
    if kind != "auto":
        return kind
    pinned = _AUTO_KIND.get()
    if pinned is not None:
        return pinned
    return "pcg-two-level" if HAVE_CHOLMOD and num_vertices >= TWO_LEVEL_MIN_VERTICES else "pcg"


class LinearSolver:
    """Solves (blocks) dv = rhs with dv fixed on constrained vertices.

    kind: 'cholmod' (exact, reuses the symbolic analysis), 'splu' (exact, SciPy),
    'pcg-two-level' (iterative, relative residual `tol`, two-level preconditioner) or
    'pcg' (the same with block-Jacobi alone). 'auto' is the two-level PCG from 1,500
    vertices, block-Jacobi below (`resolve_kind`). Warm-started from the previous step,
    the two-level PCG needs 20-100 iterations on cloths and 100-200 on garments in
    contact, where block-Jacobi needs 150-450 (docs/ENGINE.md); the direct solvers remain
    for exact solves.
    """

    def __init__(self, pattern: BlockPattern, kind: str = "auto", tol: float = 1e-6, max_iter: int = 2000):
        if kind not in SOLVER_KINDS:
            raise SimulationError(f"unknown linear solver {kind!r}; use {', '.join(SOLVER_KINDS)}")
        kind = resolve_kind(kind, pattern.n)
        if kind in ("cholmod", "pcg-two-level") and not HAVE_CHOLMOD:
            raise SimulationError(_NEEDS_CHOLMOD.format(kind=kind))
        self.kind = kind
        self.pattern = pattern
        self.tol = tol
        self.max_iter = max_iter
        self.coarse = CoarseSpace(pattern) if kind == "pcg-two-level" else None
        self._factor = None
        self._symbolic = None  # CHOLMOD analysis of `solve_factorized`
        self.last_iterations = 0
        self.direct_fallbacks = 0  # PCG solves that did not converge and were redone directly
        self.coarse_failures = 0  # two-level solves whose coarse matrix could not be factorised

    def solve(self, blocks: np.ndarray, rhs: np.ndarray, fixed: np.ndarray, fixed_values: np.ndarray, guess: np.ndarray | None = None) -> np.ndarray:
        """rhs [N,3]; fixed: bool [N]; fixed_values [k,3] for the fixed vertices in order."""
        if self.kind in ("pcg", "pcg-two-level"):
            return self._solve_pcg(blocks, rhs, fixed, fixed_values, guess)
        return self._solve_direct(blocks, rhs, fixed, fixed_values)

    def _iterate(self, blocks, rhs, x, free) -> int:
        p = self.pattern
        if self.coarse is not None:
            try:
                return two_level_pcg(p, self.coarse, blocks, rhs, x, free, self.tol, self.max_iter)
            except CoarseSolveError:
                self.coarse_failures += 1  # x is untouched: block-Jacobi solves this system
        return filtered_pcg(p.indptr, p.indices, blocks, p.diag_block, rhs, x, free, self.tol, self.max_iter)

    def _solve_pcg(self, blocks, rhs, fixed, fixed_values, guess):
        x = np.zeros_like(rhs) if guess is None else guess.copy()
        x[fixed] = fixed_values
        self.last_iterations = self._iterate(blocks, rhs, x, ~fixed)
        if self.last_iterations >= self.max_iter or not np.all(np.isfinite(x)):
            # stiff contact can leave PCG far from converged; its iterate is then no
            # solution at all, so this system is solved exactly instead
            self.direct_fallbacks += 1
            kind, self.kind = self.kind, ("cholmod" if HAVE_CHOLMOD else "splu")
            try:
                x = self._solve_direct(blocks, rhs, fixed, fixed_values)
            finally:
                self.kind = kind
            self.last_iterations = self.max_iter
        return x

    def _solve_direct(self, blocks, rhs, fixed, fixed_values):
        A, b = reduced_system(self.pattern, blocks, rhs, fixed, fixed_values)
        if self.kind == "cholmod":
            if self._factor is None:
                self._factor = _cholmod_analyze(A, mode="supernodal", ordering_method="best")
            self._factor.cholesky_inplace(A)
            sol = self._factor(b.reshape(-1))
        else:
            sol = spla.splu(A, permc_spec="MMD_AT_PLUS_A").solve(b.reshape(-1))
        self.last_iterations = 1
        return np.asarray(sol).reshape(-1, 3)

    def solve_factorized(self, blocks: np.ndarray, rhs: np.ndarray, fixed: np.ndarray,
                         fixed_values: np.ndarray) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
        """A direct solve that keeps its factorisation: (dv [N,3], solve) where `solve(b)`
        solves the same reduced system (pinned vertices eliminated, `reduced_system`) for
        another right-hand side, e.g. the adjoint of `tryon.diff`. CHOLMOD's symbolic
        analysis is reused across calls; without CHOLMOD, SuperLU."""
        A, b = reduced_system(self.pattern, blocks, rhs, fixed, fixed_values)
        if HAVE_CHOLMOD:
            if self._symbolic is None:
                self._symbolic = _cholmod_analyze(A, mode="supernodal", ordering_method="best")
            solve = self._symbolic.cholesky(A)
        else:
            solve = spla.splu(A, permc_spec="MMD_AT_PLUS_A").solve
        self.last_iterations = 1
        return np.asarray(solve(b.reshape(-1))).reshape(-1, 3), solve
