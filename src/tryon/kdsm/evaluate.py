"""How well each method's targets represent a pose dataset, before any learning (the KDSM
paper's Table 1): the error of the cloth rebuilt from the exact target (what a perfect
network would give) and how much the target jumps between consecutive poses of a
sequence (|delta d|: what makes a target hard to learn)."""

from __future__ import annotations

import time

import numpy as np

from tryon.kdsm.rig import KdsmRig

TARGET_METHODS = ("jin-uvn", "kdsm-method1", "kdsm-method2", "kdsm-hybrid")


def sequence_targets(rig: KdsmRig, x: np.ndarray, poses: np.ndarray, methods=TARGET_METHODS) -> dict:
    """For one sequence (cloth [F,n,3], poses [F,J,3]): every method's targets [F,n,3],
    the positions rebuilt from them [F,n,3] and the skinning baseline's [F,n,3]."""
    out = {m: {"target": [], "rebuilt": []} for m in methods}
    out["skinning"] = {"rebuilt": []}
    for xf, pose in zip(x.astype(np.float64), poses):
        G = rig.transforms(pose)
        body = rig.body(G)
        out["skinning"]["rebuilt"].append(rig.skinned(G))
        for m in methods:
            t = rig.target(m, xf, G, body)
            out[m]["target"].append(t)
            out[m]["rebuilt"].append(rig.positions(m, t, G, body))
    return {m: {k: np.stack(v) for k, v in d.items()} for m, d in out.items()}


def generation_table(rig: KdsmRig, x: np.ndarray, poses: np.ndarray, progress: bool = False) -> list[dict]:
    """Table 1 over sequences (cloth [S,F,n,3], poses [S,F,J,3]): per method, the rebuilt
    cloth's vertex error (cm, mean and max) and the target's change between consecutive
    poses (cm, mean and max over vertices and pose pairs)."""
    err: dict[str, list] = {}
    jump: dict[str, list] = {}
    t0 = time.perf_counter()
    for s in range(len(x)):
        res = sequence_targets(rig, x[s], poses[s])
        for m, d in res.items():
            err.setdefault(m, []).append(100.0 * np.linalg.norm(d["rebuilt"] - x[s], axis=-1).ravel())
            if "target" in d:
                jump.setdefault(m, []).append(100.0 * np.linalg.norm(np.diff(d["target"], axis=0), axis=-1).ravel())
        if progress:
            print(f"targets: sequence {s + 1}/{len(x)} ({time.perf_counter() - t0:.0f} s)", flush=True)
    rows = []
    for m in err:
        e = np.concatenate(err[m])
        row = {"method": m, "generation_mean_error_cm": float(e.mean()), "generation_max_error_cm": float(e.max())}
        if m in jump:
            j = np.concatenate(jump[m])
            row.update({"mean_delta_d_cm": float(j.mean()), "max_delta_d_cm": float(j.max())})
        rows.append(row)
    return rows
