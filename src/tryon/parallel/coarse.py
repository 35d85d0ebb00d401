"""The coarse run of a time-parallel simulation: the cheap predictor whose states start
the fine segments. It steps one coarse step (dt_ratio fine steps) at a time when the
driver asks, keeps every state it reaches (they are small) and measures its cost."""

from __future__ import annotations


import numpy as np
import torch

from tryon.errors import SimulationError
from tryon.parallel.hierarchy import Hierarchy
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim import loop
from tryon.sim.model import ClothState


class CoarseRun:
    """States of the coarse cloth by fine step index (multiples of the dt ratio)."""

    def __init__(self, hier: Hierarchy, trajectory: dict[int, tuple[np.ndarray, np.ndarray]] | None = None):
        self.hier = hier
        self.r = hier.dt_ratio
        self.solver = ImplicitEulerSolver(hier.coarse.model, hier.coarse.options)
        self.states: dict[int, tuple[np.ndarray, np.ndarray]] = dict(trajectory or {})
        if not self.states:
            s0 = hier.coarse.model.initial_state()
            self.states[0] = (s0.x.numpy().copy(), s0.v.numpy().copy())
        self.position = max(self.states)
        self.seconds: list[float] = []

    def advance(self) -> int:
        """One coarse step; returns the new position (in fine steps)."""
        x, v = self.states[self.position]
        t = self.position * self.hier.fine.dt
        state = ClothState(torch.from_numpy(x.copy()), torch.from_numpy(v.copy()), t)
        rec = loop.advance(self.solver, state, self.hier.coarse.dt)
        new = rec.state
        self.seconds.append(rec.seconds)
        self.position += self.r
        self.states[self.position] = (new.x.numpy().copy(), new.v.numpy().copy())
        return self.position

    def cost_per_fine_step(self) -> float | None:
        """Measured coarse seconds per fine step of simulated time (None before a step)."""
        if not self.seconds:
            return None
        return float(np.mean(self.seconds)) / self.r

    def has_start(self, start: int) -> bool:
        """Whether the states a segment starting at `start` needs exist."""
        return start == 0 or (start in self.states and start + self.r in self.states)

    def start_pair(self, start: int) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """Coarse (x, v) at `start` and one fine step later (linear in time between coarse steps)."""
        if not self.has_start(start) or start not in self.states:
            raise SimulationError(f"the coarse run has not reached step {start + self.r} needed to start a segment at {start}")
        x0, v0 = self.states[start]
        x1, v1 = self.states[start + self.r]
        return (x0, v0), (x0 + (x1 - x0) / self.r, v0 + (v1 - v0) / self.r)

    def arrays(self) -> dict[str, np.ndarray]:
        """The trajectory as arrays for a checkpoint."""
        keys = sorted(self.states)
        return {"steps": np.asarray(keys, np.int64), "x": np.stack([self.states[k][0] for k in keys]),
                "v": np.stack([self.states[k][1] for k in keys])}

    @staticmethod
    def trajectory_from(arrays: dict) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        return {int(k): (x, v) for k, x, v in zip(arrays["steps"], arrays["x"], arrays["v"])}
