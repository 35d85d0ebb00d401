"""Bounding volume hierarchies over axis-aligned boxes, as numba kernels.

Build: primitives are sorted along a 63-bit Morton curve of their box centres and the
tree is split top-down at the highest differing Morton bit of each range (the linear BVH
of Lauterbach et al. 2009 / Karras 2012, built sequentially). Nodes are stored so that
children always follow their parent, which makes `refit` a single reverse sweep.

Queries: box-overlap pair traversal of two trees (A vs B) or of a tree against itself
(each unordered pair once), with an explicit, growable stack; results go into growable
buffers. Nearest-face queries for points prune by box distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tryon.sim.geometry.primitives import jit
from tryon.sim.geometry.threads import chunked

LEAF_SIZE = 4


# --------------------------------------------------------------------------- boxes
@jit
def element_boxes(x: np.ndarray, elems: np.ndarray, margin: float):
    """Boxes [K,3] (lo, hi) of elements (rows of vertex ids) at positions x, inflated by margin."""
    k, m = elems.shape
    lo = np.empty((k, 3))
    hi = np.empty((k, 3))
    for e in range(k):
        for d in range(3):
            v = x[elems[e, 0], d]
            a = v
            b = v
            for j in range(1, m):
                v = x[elems[e, j], d]
                a = min(a, v)
                b = max(b, v)
            lo[e, d] = a - margin
            hi[e, d] = b + margin
    return lo, hi


@jit
def swept_boxes(x0: np.ndarray, x1: np.ndarray, elems: np.ndarray, margin: float):
    """Boxes enclosing elements at both x0 and x1 (hence their whole linear motion)."""
    k, m = elems.shape
    lo = np.empty((k, 3))
    hi = np.empty((k, 3))
    for e in range(k):
        for d in range(3):
            a = x0[elems[e, 0], d]
            b = a
            for j in range(m):
                v0 = x0[elems[e, j], d]
                v1 = x1[elems[e, j], d]
                a = min(a, v0, v1)
                b = max(b, v0, v1)
            lo[e, d] = a - margin
            hi[e, d] = b + margin
    return lo, hi


@jit
def point_boxes(x: np.ndarray, margin: float):
    n = x.shape[0]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    for i in range(n):
        for d in range(3):
            lo[i, d] = x[i, d] - margin
            hi[i, d] = x[i, d] + margin
    return lo, hi


@jit
def swept_point_boxes(x0: np.ndarray, x1: np.ndarray, margin: float):
    n = x0.shape[0]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    for i in range(n):
        for d in range(3):
            lo[i, d] = min(x0[i, d], x1[i, d]) - margin
            hi[i, d] = max(x0[i, d], x1[i, d]) + margin
    return lo, hi


# --------------------------------------------------------------------------- build
@jit
def _expand_bits(v):
    """Spread the low 21 bits of v so that two zero bits separate consecutive bits."""
    v &= 0x1FFFFF
    v = (v | (v << 32)) & 0x1F00000000FFFF
    v = (v | (v << 16)) & 0x1F0000FF0000FF
    v = (v | (v << 8)) & 0x100F00F00F00F00F
    v = (v | (v << 4)) & 0x10C30C30C30C30C3
    v = (v | (v << 2)) & 0x1249249249249249
    return v


@jit
def _morton_codes(lo: np.ndarray, hi: np.ndarray):
    n = lo.shape[0]
    cmin = np.full(3, np.inf)
    cmax = np.full(3, -np.inf)
    for i in range(n):
        for d in range(3):
            c = 0.5 * (lo[i, d] + hi[i, d])
            cmin[d] = min(cmin[d], c)
            cmax[d] = max(cmax[d], c)
    codes = np.empty(n, np.int64)
    res = float((1 << 21) - 1)
    for i in range(n):
        code = 0
        for d in range(3):
            ext = cmax[d] - cmin[d]
            c = 0.5 * (lo[i, d] + hi[i, d])
            q = 0
            if ext > 0.0:
                q = int((c - cmin[d]) / ext * res)
            code |= _expand_bits(q) << (2 - d)
        codes[i] = code
    return codes


@jit
def _split_index(codes: np.ndarray, start: int, end: int) -> int:
    """First index of the upper half of [start, end) at the highest differing Morton bit;
    the middle when all codes are equal."""
    first = codes[start]
    last = codes[end - 1]
    if first == last:
        return (start + end) // 2
    diff = first ^ last
    bit = 62
    while bit > 0 and ((diff >> bit) & 1) == 0:
        bit -= 1
    lo_i = start
    hi_i = end - 1  # codes[hi_i] has the bit set, codes[start] has not
    while hi_i - lo_i > 1:
        mid = (lo_i + hi_i) // 2
        if (codes[mid] >> bit) & 1:
            hi_i = mid
        else:
            lo_i = mid
    return hi_i


def build_tree(lo: np.ndarray, hi: np.ndarray, leaf_size: int):
    """Topology of a BVH over boxes: (order [n], child [K,2], first [K], count [K]).
    Leaves have child = -1 and hold primitives order[first : first + count]."""
    codes = _morton_codes(lo, hi)
    order = np.argsort(codes, kind="stable")  # numpy's radix/timsort beats numba's sort here
    child, first, count = _split_nodes(codes[order], leaf_size)
    return order, child, first, count


@jit
def _split_nodes(scodes: np.ndarray, leaf_size: int):
    n = scodes.shape[0]
    cap = max(2 * n, 1)
    child = np.full((cap, 2), -1, np.int64)
    first = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    stack = np.empty((128, 3), np.int64)
    sp = 0
    n_nodes = 1
    stack[0, 0] = 0
    stack[0, 1] = 0
    stack[0, 2] = n
    sp = 1
    while sp > 0:
        sp -= 1
        node = stack[sp, 0]
        s = stack[sp, 1]
        e = stack[sp, 2]
        first[node] = s
        count[node] = e - s
        if e - s <= leaf_size:
            continue
        m = _split_index(scodes, s, e)
        left = n_nodes
        right = n_nodes + 1
        n_nodes += 2
        child[node, 0] = left
        child[node, 1] = right
        if sp + 2 > stack.shape[0]:
            stack = _grow(stack)
        stack[sp, 0] = left
        stack[sp, 1] = s
        stack[sp, 2] = m
        stack[sp + 1, 0] = right
        stack[sp + 1, 1] = m
        stack[sp + 1, 2] = e
        sp += 2
    return child[:n_nodes].copy(), first[:n_nodes].copy(), count[:n_nodes].copy()


@jit
def _grow(a: np.ndarray) -> np.ndarray:
    out = np.empty((2 * a.shape[0],) + a.shape[1:], a.dtype)
    out[: a.shape[0]] = a
    return out


@jit
def refit_tree(order, child, first, count, lo, hi):
    """Node boxes (lo, hi) [K,3] of a tree for the current primitive boxes (bottom-up)."""
    k = child.shape[0]
    nlo = np.empty((k, 3))
    nhi = np.empty((k, 3))
    for node in range(k - 1, -1, -1):
        if child[node, 0] < 0:
            for d in range(3):
                nlo[node, d] = np.inf
                nhi[node, d] = -np.inf
            for j in range(first[node], first[node] + count[node]):
                p = order[j]
                for d in range(3):
                    nlo[node, d] = min(nlo[node, d], lo[p, d])
                    nhi[node, d] = max(nhi[node, d], hi[p, d])
        else:
            a = child[node, 0]
            b = child[node, 1]
            for d in range(3):
                nlo[node, d] = min(nlo[a, d], nlo[b, d])
                nhi[node, d] = max(nhi[a, d], nhi[b, d])
    return nlo, nhi


# --------------------------------------------------------------------------- queries
@jit
def _overlap(alo, ahi, i, blo, bhi, j) -> bool:
    # bitwise & instead of `and`: one unpredictable branch instead of six (4x faster)
    return (
        (alo[i, 0] <= bhi[j, 0])
        & (blo[j, 0] <= ahi[i, 0])
        & (alo[i, 1] <= bhi[j, 1])
        & (blo[j, 1] <= ahi[i, 1])
        & (alo[i, 2] <= bhi[j, 2])
        & (blo[j, 2] <= ahi[i, 2])
    )


@jit
def _size(lo, hi, i) -> float:
    """Half perimeter of a box (its volume is zero for flat geometry)."""
    return (hi[i, 0] - lo[i, 0]) + (hi[i, 1] - lo[i, 1]) + (hi[i, 2] - lo[i, 2])


@jit
def _descend(a, b, a_child, a_nlo, a_nhi, b_child, b_nlo, b_nhi, same, stack, sp):
    """One step of the simultaneous descent from node pair (a, b): pushes the child pairs
    to visit onto `stack` (grown as needed) and returns (stack, new sp, leaf pair?)."""
    if sp + 3 > stack.shape[0]:
        stack = _grow(stack)
    a_leaf = a_child[a, 0] < 0
    if same and a == b:
        if not a_leaf:
            l_ = a_child[a, 0]
            r_ = a_child[a, 1]
            stack[sp, 0] = l_
            stack[sp, 1] = l_
            stack[sp + 1, 0] = r_
            stack[sp + 1, 1] = r_
            stack[sp + 2, 0] = l_
            stack[sp + 2, 1] = r_
            return stack, sp + 3, False
    elif not _overlap(a_nlo, a_nhi, a, b_nlo, b_nhi, b):
        return stack, sp, False
    b_leaf = b_child[b, 0] < 0
    if a_leaf and b_leaf:
        return stack, sp, True
    if a_leaf or (not b_leaf and _size(a_nlo, a_nhi, a) < _size(b_nlo, b_nhi, b)):
        stack[sp, 0] = a
        stack[sp, 1] = b_child[b, 0]
        stack[sp + 1, 0] = a
        stack[sp + 1, 1] = b_child[b, 1]
    else:
        stack[sp, 0] = a_child[a, 0]
        stack[sp, 1] = b
        stack[sp + 1, 0] = a_child[a, 1]
        stack[sp + 1, 1] = b
    return stack, sp + 2, False


@jit
def overlap_roots(a_child, a_nlo, a_nhi, b_child, b_nlo, b_nhi, same, wanted):
    """Node pairs [R,2] whose subtrees hold every overlapping pair once: the descent from
    the roots, breadth first, until at least `wanted` pairs (or only leaf pairs) remain.
    Independent tasks for `overlap_pairs`, the same for any number of threads."""
    if a_child.shape[0] == 0 or b_child.shape[0] == 0:
        return np.zeros((0, 2), np.int64)
    level = np.zeros((1, 2), np.int64)
    while level.shape[0] < wanted:
        nxt = np.empty((3 * level.shape[0] + 3, 2), np.int64)
        sp = 0
        split = False
        for q in range(level.shape[0]):
            a = level[q, 0]
            b = level[q, 1]
            nxt, sp2, leaf = _descend(a, b, a_child, a_nlo, a_nhi, b_child, b_nlo, b_nhi, same, nxt, sp)
            if leaf:
                nxt[sp2, 0] = a
                nxt[sp2, 1] = b
                sp2 += 1
            else:
                split = True
            sp = sp2
        level = nxt[:sp].copy()
        if not split:
            break
    return level


@jit
def overlap_pairs(a_order, a_child, a_first, a_count, a_nlo, a_nhi, a_lo, a_hi,
                  b_order, b_child, b_first, b_count, b_nlo, b_nhi, b_lo, b_hi, same, roots):
    """All pairs (i, j) of primitives of trees A and B whose boxes overlap, by simultaneous
    descent with an explicit stack from the node pairs `roots` ([[0, 0]]: from the roots).
    With same=True (B is A) each unordered pair i != j is reported once."""
    out = np.empty((max(16, 4 * (a_lo.shape[0] + b_lo.shape[0]) // max(1, roots.shape[0])), 2), np.int64)
    k = 0
    if a_child.shape[0] == 0 or b_child.shape[0] == 0:
        return out[:0]
    stack = np.empty((256, 2), np.int64)
    for r in range(roots.shape[0]):
        stack[0, 0] = roots[r, 0]
        stack[0, 1] = roots[r, 1]
        sp = 1
        while sp > 0:
            sp -= 1
            a = stack[sp, 0]
            b = stack[sp, 1]
            stack, sp, leaf = _descend(a, b, a_child, a_nlo, a_nhi, b_child, b_nlo, b_nhi, same, stack, sp)
            if not leaf:
                continue
            if k + a_count[a] * b_count[b] > out.shape[0]:
                out = _grow(out)
            for u in range(a_first[a], a_first[a] + a_count[a]):
                i = a_order[u]
                v0 = b_first[b]
                if same and a == b:
                    v0 = u + 1
                for v in range(v0, b_first[b] + b_count[b]):
                    j = b_order[v]
                    if _overlap(a_lo, a_hi, i, b_lo, b_hi, j):
                        out[k, 0] = i
                        out[k, 1] = j
                        k += 1
    return out[:k]


@dataclass
class BVH:
    """A BVH over primitive boxes. `refit(lo, hi)` reuses the topology for moved primitives
    (cheap, but boxes loosen when the motion is large: rebuild then)."""

    order: np.ndarray
    child: np.ndarray
    first: np.ndarray
    count: np.ndarray
    node_lo: np.ndarray
    node_hi: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def build(cls, lo: np.ndarray, hi: np.ndarray, leaf_size: int = LEAF_SIZE) -> "BVH":
        lo = np.ascontiguousarray(lo, dtype=np.float64)
        hi = np.ascontiguousarray(hi, dtype=np.float64)
        if lo.shape[0] == 0:
            z = np.zeros((0, 3))
            e = np.zeros(0, np.int64)
            return cls(e, np.zeros((0, 2), np.int64), e, e, z, z, lo, hi)
        order, child, first, count = build_tree(lo, hi, leaf_size)
        nlo, nhi = refit_tree(order, child, first, count, lo, hi)
        return cls(order, child, first, count, nlo, nhi, lo, hi)

    def refit(self, lo: np.ndarray, hi: np.ndarray) -> None:
        self.lo = np.ascontiguousarray(lo, dtype=np.float64)
        self.hi = np.ascontiguousarray(hi, dtype=np.float64)
        if self.lo.shape[0]:
            self.node_lo, self.node_hi = refit_tree(self.order, self.child, self.first, self.count, self.lo, self.hi)

    def __len__(self) -> int:
        return int(self.lo.shape[0])

    def arrays(self) -> tuple:
        return (self.order, self.child, self.first, self.count, self.node_lo, self.node_hi, self.lo, self.hi)


# Subtree pairs a query is cut into (`overlap_roots`), handed out in chunks to the threads.
QUERY_TASKS, TASKS_PER_CHUNK = 64, 4


def overlapping_pairs(a: BVH, b: BVH | None = None) -> np.ndarray:
    """Pairs [K,2] (i in A, j in B) of primitives with overlapping boxes; b=None: A with
    itself, each unordered pair once. Subtrees are searched on numba's threads (`chunked`);
    the pairs and their order do not depend on the number of threads."""
    same = b is None
    b = a if b is None else b
    roots = overlap_roots(a.child, a.node_lo, a.node_hi, b.child, b.node_lo, b.node_hi, same, QUERY_TASKS)
    parts = chunked(lambda part: overlap_pairs(*a.arrays(), *b.arrays(), same, part), roots, TASKS_PER_CHUNK)
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


# --------------------------------------------------------------------------- nearest face
@jit
def _box_dist2(nlo, nhi, node, p):
    d2 = 0.0
    for d in range(3):
        if p[d] < nlo[node, d]:
            t = nlo[node, d] - p[d]
            d2 += t * t
        elif p[d] > nhi[node, d]:
            t = p[d] - nhi[node, d]
            d2 += t * t
    return d2
