"""How well each method's targets represent a pose dataset, before any learning (the KDSM
paper's Table 1): the error of the cloth rebuilt from the exact target (what a perfect
network would give), how much the target jumps between consecutive poses of a sequence
(|delta d|) and how far it spreads over all the poses (what a network must learn: a
target that moves less with the pose leaves it less to get wrong)."""

from __future__ import annotations

import time

import numpy as np

from tryon.kdsm.embed import smooth_offsets
from tryon.kdsm.rig import HYBRID_SMOOTHING, KdsmRig

TARGET_METHODS = ("jin-uvn", "kdsm-method1", "kdsm-method2", "kdsm-hybrid")


def sequence_targets(rig: KdsmRig, x: np.ndarray, poses: np.ndarray, methods=TARGET_METHODS,
                     smoothing: float = HYBRID_SMOOTHING) -> dict:
    """For one sequence (cloth [F,n,3], poses [F,J,3]): every method's targets [F,n,3]
    (the hybrid's smoothed with `smoothing`), the positions rebuilt from them [F,n,3] and
    the skinning baseline's [F,n,3]."""
    return {m: d for (m, _), d in _targets(rig, x, poses, methods, (smoothing,)).items()}


def _targets(rig: KdsmRig, x: np.ndarray, poses: np.ndarray, methods, smoothings) -> dict:
    """`sequence_targets` keyed by (method, smoothing), the hybrid's at every one of
    `smoothings` (its embedding made once per pose; only the smoothing differs)."""
    keys = [(m, s) for m in methods for s in (smoothings if m == "kdsm-hybrid" else (None,))]
    out = {k: {"target": [], "rebuilt": []} for k in keys}
    out[("skinning", None)] = {"rebuilt": []}
    for xf, pose in zip(x.astype(np.float64), poses):
        G = rig.transforms(pose)
        body = rig.body(G)
        out[("skinning", None)]["rebuilt"].append(rig.skinned(G))
        for m in methods:
            if m == "kdsm-hybrid":
                raw = rig.target(m, xf, G, body, smoothing=0.0)
                targets = {s: smooth_offsets(raw, rig.faces, s) for s in smoothings}
            else:
                targets = {None: rig.target(m, xf, G, body)}
            for s, t in targets.items():
                out[(m, s)]["target"].append(t)
                out[(m, s)]["rebuilt"].append(rig.positions(m, t, G, body))
    return {k: {name: np.stack(v) for name, v in d.items()} for k, d in out.items()}


def generation_table(rig: KdsmRig, x: np.ndarray, poses: np.ndarray, progress: bool = False,
                     smoothings=(HYBRID_SMOOTHING,), methods=TARGET_METHODS) -> list[dict]:
    """Table 1 over sequences (cloth [S,F,n,3], poses [S,F,J,3]): per method, the rebuilt
    cloth's vertex error (cm, mean and max), the target's change between consecutive
    poses (cm, mean and max over vertices and pose pairs) and its spread over all the
    poses (`pose_spread_cm`: per vertex, the RMS distance of its target from the target's
    mean over the poses; the mean and 95th percentile over vertices). Skinning's row, one
    per method in `methods`, the hybrid's one per value of `smoothings` (recorded in its row)."""
    err: dict[tuple, list] = {}
    jump: dict[tuple, list] = {}
    spread: dict[tuple, TargetSpread] = {}
    t0 = time.perf_counter()
    for s in range(len(x)):
        res = _targets(rig, x[s], poses[s], methods, tuple(smoothings))
        for key, d in res.items():
            err.setdefault(key, []).append(100.0 * np.linalg.norm(d["rebuilt"] - x[s], axis=-1).ravel())
            if "target" in d:
                jump.setdefault(key, []).append(100.0 * np.linalg.norm(np.diff(d["target"], axis=0), axis=-1).ravel())
                spread.setdefault(key, TargetSpread()).add(d["target"])
        if progress:
            print(f"targets: sequence {s + 1}/{len(x)} ({time.perf_counter() - t0:.0f} s)", flush=True)
    rows = []
    for (m, smoothing), errors in err.items():
        e = np.concatenate(errors)
        row = {"method": m, "generation_mean_error_cm": float(e.mean()), "generation_max_error_cm": float(e.max())}
        if smoothing is not None:
            row["smoothing"] = float(smoothing)
        if (m, smoothing) in jump:
            j = np.concatenate(jump[(m, smoothing)])
            row.update({"mean_delta_d_cm": float(j.mean()), "max_delta_d_cm": float(j.max())})
            per_vertex = spread[(m, smoothing)].per_vertex_cm()
            row.update({"pose_spread_cm": float(per_vertex.mean()),
                        "pose_spread_p95_cm": float(np.percentile(per_vertex, 95))})
        rows.append(row)
    return rows


class TargetSpread:
    """Running per-vertex sums of a target over poses, for its spread about its mean."""

    def __init__(self) -> None:
        self.count = 0
        self.total: np.ndarray | None = None       # [n,3] sum of the targets
        self.total_sq: np.ndarray | None = None    # [n] sum of their squared lengths

    def add(self, targets: np.ndarray) -> None:
        """Targets [F,n,3] of F more poses."""
        t = np.asarray(targets, np.float64)
        self.count += len(t)
        self.total = t.sum(0) if self.total is None else self.total + t.sum(0)
        sq = (t * t).sum((0, 2))
        self.total_sq = sq if self.total_sq is None else self.total_sq + sq

    def per_vertex_cm(self) -> np.ndarray:
        """Each vertex's RMS distance from its mean target [n] (cm)."""
        if not self.count:
            raise ValueError("no targets were added")
        mean = self.total / self.count
        return 100.0 * np.sqrt(np.maximum(self.total_sq / self.count - (mean * mean).sum(1), 0.0))


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """The mesh's boundary loops, each as ordered vertex ids (a garment's openings)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(e, 1)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    directed = e[count[inv.ravel()] == 1]                      # boundary edges, in their face's direction
    nxt = dict(zip(directed[:, 0].tolist(), directed[:, 1].tolist()))
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        loops.append(np.asarray(loop))
    return loops


def capped_faces(faces: np.ndarray, n: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Faces closing every opening with a fan to a new vertex at the opening's centroid
    (vertex ids n, n+1, ... in loop order), and the loops."""
    loops = boundary_loops(faces)
    caps = []
    for k, loop in enumerate(loops):
        c = n + k
        caps.append(np.stack([loop[1:].tolist() + [loop[0]], loop, np.full(len(loop), c)], 1))
    return np.concatenate([faces] + caps) if caps else faces, loops


def enclosed_volume(x: np.ndarray, faces: np.ndarray, capped: tuple[np.ndarray, list[np.ndarray]] | None = None) -> float:
    """Volume (m³) the garment encloses with its openings capped (divergence theorem over
    the closed surface; its sign made positive)."""
    cf, loops = capped if capped is not None else capped_faces(faces, len(x))
    pts = np.concatenate([x] + [x[loop].mean(0, keepdims=True) for loop in loops])
    a, b, c = pts[cf[:, 0]], pts[cf[:, 1]], pts[cf[:, 2]]
    return abs(float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum()) / 6.0)
