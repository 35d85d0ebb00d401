"""The simulation time step for an observed sequence, chosen by a convergence check.

An observation from a camera (or another simulator) does not say which time step
reproduces it: the step is a property of our discretisation, not of the cloth. The
check simulates the first quarter of the sequence with a candidate fabric at
``dt = frame_time / k`` for k = 1, 2, 4, ... and takes the largest step whose result
changes by less than `DT_TOLERANCE` (mean vertex distance over the frames, over the
cloth's diagonal) when the step is halved. Implicit Euler is first order, so that change
estimates the step's own discretisation error.

Only the first quarter is compared: a cloth flapping in wind is chaotic over seconds
(two runs that differ by round-off drift apart by centimetres after 1-2 s), so a
comparison over the whole sequence never settles, while the early motion converges like
the integrator's order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tryon.diff.observed import Observation, simulate_frames
from tryon.errors import SimulationError
from tryon.fabric.base import Fabric

DT_TOLERANCE = 0.002  # 0.2 % of the cloth size: well below the 1-2 % errors a fit is judged by
MAX_START_DT = 0.04  # s: the first candidate is the largest step <= this that divides a frame
MAX_HALVINGS = 6


@dataclass
class TimeStepChoice:
    """The chosen step and the checks that chose it: (dt, change when halved) pairs."""

    dt: float
    converged: bool
    frames: int
    checks: list[tuple[float, float]] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"dt": self.dt, "converged": self.converged, "frames_checked": self.frames,
                "tolerance": DT_TOLERANCE,
                "checks": [{"dt": dt, "change_when_halved": change} for dt, change in self.checks]}


def check_horizon(num_frames: int) -> int:
    """Frames compared by the check: the first quarter (at least 2)."""
    return max(2, (num_frames + 3) // 4)


def choose_dt(obs: Observation, fabric: Fabric, tolerance: float = DT_TOLERANCE) -> TimeStepChoice:
    """The largest step whose halving changes the early motion by < `tolerance` (module docstring)."""
    frames = min(obs.num_frames, check_horizon(obs.num_frames))
    k = max(1, math.ceil(obs.frame_time / MAX_START_DT - 1e-9))
    model = obs.model(fabric)
    size = obs.cloth_size()
    checks: list[tuple[float, float]] = []
    coarse = _simulate(model, frames, k, obs.frame_time)
    for _ in range(MAX_HALVINGS):
        fine = _simulate(model, frames, 2 * k, obs.frame_time)
        change = float("inf") if coarse is None or fine is None else \
            float(np.linalg.norm(coarse[1:] - fine[1:], axis=-1).mean()) / size
        checks.append((obs.frame_time / k, change))
        if change < tolerance:
            return TimeStepChoice(obs.frame_time / k, True, frames, checks)
        coarse, k = fine, 2 * k
    return TimeStepChoice(obs.frame_time / k, False, frames, checks)


def _simulate(model, frames: int, steps_per_frame: int, frame_time: float) -> np.ndarray | None:
    try:
        return simulate_frames(model, frames, steps_per_frame, frame_time / steps_per_frame)
    except SimulationError:  # too large a step for this cloth: not converged
        return None
