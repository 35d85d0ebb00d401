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

from tryon.diff.observed import simulate_frames
from tryon.errors import SimulationError

FD_STEP = 1e-2  # in log-multiplier units: a 1 % change of the group
WEAK = 1e-4  # eigenvalues of J^T J below this fraction of the largest: directions the motion does not show
CONSTRAINED = 0.25  # a group the motion pins down within 25 % counts as determined


def residual(est, theta: np.ndarray, frames: int) -> np.ndarray | None:
    """(simulated - observed) / size over frames 1..frames-1 of the fit `est` (a
    `FabricEstimator`) at `theta`, flattened: a plain forward run, counted in the
    estimator's work; None when the simulation fails (a candidate too far off)."""
    est.simulations += 1
    est.steps += (frames - 1) * est.spf
    try:
        x = simulate_frames(est.model, frames, est.spf, est.dt, fabric=est.fabric(theta, "candidate"))
    except SimulationError:
        return None
    return ((x[1:] - est.obs.positions[1:frames]) / est.size).reshape(-1)


def forward_jacobian(est, theta: np.ndarray, r: np.ndarray, frames: int, free: list[int], step: float,
                     bound: float = np.inf, progress=None) -> np.ndarray:
    """d residual / d theta for the `free` groups by forward differences from `r` (the
    residual at theta), one simulation each; the step turns back where it would pass
    `bound`, and a probe that does not simulate leaves its column zero."""
    J = np.zeros((len(r), len(free)))
    for col, g in enumerate(free):
        th = theta.copy()
        h = step if th[g] + step <= bound else -step
        th[g] += h
        probe = residual(est, th, frames)
        J[:, col] = 0.0 if probe is None else (probe - r) / h
        if progress is not None:
            progress.update(1)
    return J


def identifiability(est, theta: np.ndarray, group_names: tuple[str, ...], free: list[int]) -> dict:
    """The report of the module docstring for the fit `est` (a `FabricEstimator`) at `theta`."""
    frames = min(est.obs.num_frames, max(3, (est.obs.num_frames + 1) // 2))
    r0 = residual(est, theta, frames)
    if r0 is None:
        raise SimulationError("identifiability: the fitted fabric does not simulate")
    J = forward_jacobian(est, theta, r0, frames, free, FD_STEP)
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
