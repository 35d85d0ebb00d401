"""Density and handle stiffness from the cloth's momentum balance, before any simulation.

Summed over every vertex, the internal (stretching, bending) forces of the cloth cancel,
whatever the material model. What is left is Newton's law for the whole cloth::

    rho sum_i A_i (a_i - g)  +  k sum_p (x_p - x_p(0))  =  sum_i f_wind,i

with ``A_i`` the vertices' material areas, ``a_i`` accelerations from central
differences of the frames, and the second term the pull of soft handles of stiffness
``k`` (N/m per axis) on the drifting pinned vertices ``p``. Each frame gives three
equations in two unknowns (rho, k): a linear least-squares problem whose solution
depends on no elastic model at all, so density cannot absorb a mismatch between the
simulator that made the observation and ours. The standard errors come from the
residual.

Pins held exactly (no drift) transmit an unknown reaction force in every frame; then the
balance does not determine density and `momentum_estimate` returns None.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch

from tryon.diff.observed import Observation
from tryon.sim.forces.wind import wind_forces
from tryon.sim.model import ClothModel

PIN_DRIFT_MIN = 1e-4  # m: pinned vertices that move less are held exactly


@dataclass
class MomentumEstimate:
    """Least-squares density (kg/m^2) and handle stiffness (N/m) with standard errors."""

    density: float
    density_std: float
    handle_stiffness: float
    handle_stiffness_std: float
    frames: int
    relative_residual: float

    def as_dict(self) -> dict:
        return {"density_kg_m2": self.density, "density_std": self.density_std,
                "handle_stiffness_n_m": self.handle_stiffness, "handle_stiffness_std": self.handle_stiffness_std,
                "frames": self.frames, "relative_residual": self.relative_residual}


def pin_drift(obs: Observation) -> float:
    """Largest distance (m) a pinned vertex moves from its frame-0 position."""
    if len(obs.pinned) == 0:
        return 0.0
    p = obs.positions[:, obs.pinned]
    return float(np.linalg.norm(p - p[:1], axis=-1).max())


def frame_kinematics(obs: Observation, model: ClothModel, frames: range) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """(frame, velocities, accelerations, wind forces) [N, 3] per frame of `frames`, from
    central differences of the observed positions (numpy)."""
    x, tau = obs.positions, obs.frame_time
    wind = torch.as_tensor(obs.wind_velocity, dtype=torch.float64)
    for t in frames:
        v = (x[t + 1] - x[t - 1]) / (2 * tau)
        a = (x[t + 1] - 2 * x[t] + x[t - 1]) / tau**2
        f_wind, _ = wind_forces(torch.from_numpy(x[t]), torch.from_numpy(v), model.faces, model.rest_area, wind,
                                obs.wind_density, obs.wind_drag, with_jacobian=False)
        yield t, v, a, f_wind.numpy()


def momentum_estimate(obs: Observation, model: ClothModel) -> MomentumEstimate | None:
    """Solve the balance of the module docstring; None when the pins do not drift."""
    if obs.num_frames < 3 or pin_drift(obs) < PIN_DRIFT_MIN:
        return None
    x = obs.positions
    area = model.vertex_area.numpy()
    rows, rhs = [], []
    for t, _, a, f_wind in frame_kinematics(obs, model, range(1, obs.num_frames - 1)):
        drift = (x[t, obs.pinned] - x[0, obs.pinned]).sum(0)
        rows.append(np.stack([(area[:, None] * (a - obs.gravity)).sum(0), drift], axis=1))
        rhs.append(f_wind.sum(0))
    M, b = np.concatenate(rows), np.concatenate(rhs)
    scale = np.abs(M).max(0)
    sol, *_ = np.linalg.lstsq(M / scale, b, rcond=None)
    sol = sol / scale
    resid = b - M @ sol
    dof = max(1, len(b) - 2)
    cov = np.linalg.pinv(M.T @ M) * float(resid @ resid) / dof
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    rel = float(np.linalg.norm(resid) / max(np.linalg.norm(b), 1e-300))
    if not (sol[0] > 0 and sol[1] > 0):
        return None
    return MomentumEstimate(float(sol[0]), float(std[0]), float(sol[1]), float(std[1]), obs.num_frames - 2, rel)
