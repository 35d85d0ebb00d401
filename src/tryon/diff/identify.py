"""Which fabric parameters an observed motion constrains, and how well (`tryon fit-fabric`'s
``identifiability`` report).

Around the fitted parameters ``theta`` (log-multipliers of the parameter groups of
`tryon.diff.fit`), the residual ``r(theta)`` - simulated minus observed positions over the
cloth size, every coordinate of frames 1..F - is linearised by forward differences,
``J = dr/dtheta`` (one simulation per free group). The Gauss-Newton Hessian ``J^T J``
says what the motion determines:

* its eigenvalues, relative to the largest: directions below `WEAK` are (nearly) not seen
  by the motion, whatever value the fit reports for them;
* per group, an uncertainty of theta (relative, since theta is a log-multiplier):
  ``sqrt(diag(|r|^2 (J^T J)^-1))``, how far the group can move, with the others
  re-adjusting, before the misfit doubles. The residual is mostly model and time-step
  mismatch and chaos, not independent noise, so the textbook ``s^2 = |r|^2 / dof`` would
  claim a precision hundreds of times too good; the doubling range is what the motion
  actually tells apart.

Only the first half of the frames is linearised: later the flapping is chaotic and finite
differences of a 2 s trajectory measure chaos, not sensitivity.
"""

from __future__ import annotations

import numpy as np
import torch

from tryon.diff.observed import simulate_frames

FD_STEP = 1e-2  # in log-multiplier units: a 1 % change of the group
WEAK = 1e-4  # eigenvalues of J^T J below this fraction of the largest: directions the motion does not show
CONSTRAINED = 0.25  # a group the motion pins down within 25 % counts as determined


def identifiability(est, theta: np.ndarray, group_names: tuple[str, ...], free: list[int]) -> dict:
    """The report of the module docstring for the fit `est` (a `FabricEstimator`) at `theta`."""
    frames = min(est.obs.num_frames, max(3, (est.obs.num_frames + 1) // 2))
    obs_x = est.obs.positions[:frames]

    def residual(th: np.ndarray) -> np.ndarray:
        fab = est.fabric(th, "probe")
        x = simulate_frames(est.model, frames, est.spf, est.dt, fabric=fab)
        return ((x[1:] - obs_x[1:]) / est.size).reshape(-1)

    r0 = residual(theta)
    J = np.zeros((len(r0), len(free)))
    for col, g in enumerate(free):
        th = theta.copy()
        th[g] += FD_STEP
        J[:, col] = (residual(th) - r0) / FD_STEP
    JTJ = J.T @ J
    eigval, eigvec = np.linalg.eigh(JTJ)
    order = np.argsort(eigval)[::-1]
    eigval, eigvec = eigval[order], eigvec[:, order]
    top = max(float(eigval[0]), 1e-300)
    # the full inverse (a pseudo-inverse would call unseen directions certain): an unseen
    # direction gives its groups an uncertainty beyond any bound
    inv = (eigvec / np.maximum(eigval, top * 1e-12)) @ eigvec.T
    std = np.sqrt(np.maximum(float(r0 @ r0) * np.diag(inv), 0.0))
    directions = []
    for val, vec in zip(eigval, eigvec.T):
        weights = {group_names[g]: float(w) for g, w in zip(free, vec) if abs(w) >= 0.3}
        directions.append({"relative_eigenvalue": float(val) / top, "seen": float(val) / top >= WEAK,
                           "groups": weights})
    per_group = {group_names[g]: {"relative_uncertainty": float(sd), "determined": bool(sd < CONSTRAINED)}
                 for g, sd in zip(free, std)}
    return {"frames": frames, "simulations": len(free) + 1, "condition_number": top / max(float(eigval[-1]), 1e-300),
            "directions": directions, "groups": per_group,
            "note": "relative_uncertainty: change of the group (others re-adjusted) that doubles the misfit"}
