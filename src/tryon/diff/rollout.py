"""Differentiable rollouts: `DiffSimulator.rollout` runs a scene for a number of steps and
returns the trajectory as torch tensors whose gradients reach every input.

Inputs that can carry gradients:

* ``params``: the fabric's flat parameter vector (`Fabric.parameters()`; for a Wang 2011
  fabric density, 6x4 stretching and 3x5 bending data);
* ``x0``, ``v0``: the initial state;
* `Controls`: per-step external forces on chosen vertices (or a policy that computes
  them from the state, e.g. a small network), per-step wind velocity, and per-step
  targets of the pinned vertices (handle motion).

Memory: every step keeps its factorisation and contacts for the backward pass. With
``checkpoint_every=K`` only the state at every K-th step is kept; the backward pass
re-runs each segment of K steps forward (a second forward costs about as much as the
first) and then differentiates it, so a rollout of T steps holds at most K tapes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from tryon.errors import SimulationError, TryonError
from tryon.fabric.base import Fabric
from tryon.sim.integrator import StepOptions
from tryon.sim.model import ClothModel
from tryon.diff.step import FRICTION_GRADIENTS, QP_METHODS, StepContext, TapedSolver, differentiable_step

Policy = Callable[[int, torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass
class Controls:
    """Per-step inputs of a rollout (all optional, all differentiable).

    * ``forces [T, k, 3]`` (N) on ``force_vertices [k]`` (all vertices when None), held
      constant during each step; or ``policy(step, x, v) -> [k, 3]`` computing them from
      the state (a torch module's parameters then get gradients too);
    * ``wind [T, 3]`` or ``[3]`` (m/s), replacing the model's wind velocity;
    * ``handles [T, p, 3]``: positions of the pinned vertices (in `ClothModel.pinned`
      order) at the end of every step, replacing the pins' own motion.
    """

    forces: torch.Tensor | None = None
    force_vertices: torch.Tensor | None = None
    policy: Policy | None = None
    wind: torch.Tensor | None = None
    handles: torch.Tensor | None = None

    def tensors(self) -> list[torch.Tensor]:
        """Every tensor a gradient can reach through the controls (policy parameters included)."""
        out = [t for t in (self.forces, self.wind, self.handles) if t is not None]
        if isinstance(self.policy, torch.nn.Module):
            out += list(self.policy.parameters())
        return out


@dataclass
class Trajectory:
    """Positions and velocities ``[T + 1, N, 3]`` (index 0: initial state) and step statistics."""

    x: torch.Tensor
    v: torch.Tensor
    dt: float
    forward_s: float = 0.0
    substeps: int = 0
    impacts: int = 0
    fallbacks: int = 0
    stats: dict = field(default_factory=dict)


class DiffSimulator:
    """Differentiable simulation of a `ClothModel` with a fixed time step.

    ``friction_gradient``: "exact" (default) differentiates friction's lagged coefficient
    too; "constant" holds it constant in the backward pass (an approximation that is
    smoother when contacts switch between sticking and sliding). ``qp_method``: "qr"
    (default) or "kkt" for the impact-zone backward (see `tryon.diff.qp`).
    """

    def __init__(self, model: ClothModel, dt: float, fabric: Fabric | None = None, options: StepOptions | None = None,
                 friction_gradient: str = "exact", qp_method: str = "qr"):
        if not dt > 0:
            raise SimulationError(f"time step must be positive, got dt={dt}")
        if friction_gradient not in FRICTION_GRADIENTS:
            raise TryonError(f"friction_gradient must be one of {FRICTION_GRADIENTS}, got {friction_gradient!r}")
        if qp_method not in QP_METHODS:
            raise TryonError(f"qp_method must be one of {QP_METHODS}, got {qp_method!r}")
        self.model = model
        self.dt = float(dt)
        self.fabric = fabric or model.fabric
        self.solver = TapedSolver(model, options, self.fabric)
        self.ctx = StepContext(self.solver, self.fabric, friction_gradient, qp_method)
        self._pinned = torch.from_numpy(np.flatnonzero(self.solver.pinned_mask))

    # ------------------------------------------------------------------ inputs
    def parameters(self) -> torch.Tensor:
        """The fabric's parameter vector (a fresh leaf to optimise)."""
        return self.fabric.parameters().detach().clone()

    def _check(self, steps: int, params, x0, v0, controls: Controls) -> None:
        n = self.model.num_vertices
        if steps < 1:
            raise TryonError(f"a rollout needs at least one step, got {steps}")
        if params.shape != self.fabric.parameters().shape:
            raise TryonError(f"params must have shape {tuple(self.fabric.parameters().shape)} (Fabric.parameters()), got {tuple(params.shape)}")
        for name, t in (("x0", x0), ("v0", v0)):
            if t.shape != (n, 3):
                raise TryonError(f"{name} must have shape [{n}, 3], got {tuple(t.shape)}")
        k = n if controls.force_vertices is None else len(controls.force_vertices)
        if controls.forces is not None and controls.policy is not None:
            raise TryonError("give either controls.forces or controls.policy, not both")
        if controls.forces is not None and (controls.forces.ndim != 3 or controls.forces.shape[0] < steps or controls.forces.shape[1:] != (k, 3)):
            raise TryonError(f"controls.forces must have shape [>= {steps}, {k}, 3], got {tuple(controls.forces.shape)}")
        if controls.handles is not None:
            p = len(self._pinned)
            if controls.handles.ndim != 3 or controls.handles.shape[0] < steps or controls.handles.shape[1:] != (p, 3):
                raise TryonError(f"controls.handles must have shape [>= {steps}, {p}, 3] (pinned vertices), got {tuple(controls.handles.shape)}")
        if controls.wind is not None and controls.wind.shape not in ((3,),) and (controls.wind.ndim != 2 or controls.wind.shape[0] < steps or controls.wind.shape[1] != 3):
            raise TryonError(f"controls.wind must have shape [3] or [>= {steps}, 3], got {tuple(controls.wind.shape)}")

    def _step_inputs(self, k: int, x, v, controls: Controls, tensors: dict):
        """Force [N,3] or None, wind [3] or None, and the pinned-target function of step k."""
        n = self.model.num_vertices
        forces = tensors.get("forces")
        f_k = None
        if controls.policy is not None:
            f_k = controls.policy(k, x, v)
        elif forces is not None:
            f_k = forces[k]
        force = None
        if f_k is not None:
            if controls.force_vertices is None:
                force = f_k
            else:
                force = torch.zeros(n, 3, dtype=f_k.dtype).index_put((controls.force_vertices,), f_k, accumulate=True)
        wind = tensors.get("wind")
        if wind is not None and wind.ndim == 2:
            wind = wind[k]
        return force, wind, self._targets(k, x, tensors.get("handles"))

    def _targets(self, k: int, x_start: torch.Tensor, handles: torch.Tensor | None):
        """Pinned positions at time t within step k: the pins' motion, or a linear
        interpolation from the step's start to ``handles[k]``."""
        t_start = k * self.dt
        if handles is None:
            return lambda t, _x: self.model.pin_targets(t)
        start = x_start[self._pinned] if k == 0 else handles[k - 1]

        def at(t: float, _x) -> torch.Tensor:
            s = min(max((t - t_start) / self.dt, 0.0), 1.0)
            return handles[k] if s >= 1.0 else (1.0 - s) * start + s * handles[k]

        return at

    # ------------------------------------------------------------------ rollout
    def rollout(self, steps: int, params: torch.Tensor | None = None, x0: torch.Tensor | None = None,
                v0: torch.Tensor | None = None, controls: Controls | None = None, checkpoint_every: int | None = None,
                progress: bool = False) -> Trajectory:
        """Simulate ``steps`` steps from (x0, v0) (default: the model's initial state) and
        return the differentiable `Trajectory` (see the module docstring)."""
        params = self.parameters() if params is None else params
        init = self.model.initial_state()
        x0 = init.x if x0 is None else x0
        v0 = init.v if v0 is None else v0
        controls = controls or Controls()
        self._check(steps, params, x0, v0, controls)
        self.solver.set_fabric(self.fabric.with_parameters(params.detach()))
        tensors = {k: t for k, t in (("forces", controls.forces), ("wind", controls.wind), ("handles", controls.handles)) if t is not None}
        extra = controls.tensors()
        seg = checkpoint_every or steps
        xs, vs = [x0[None]], [v0[None]]
        x, v = x0, v0
        info = {"substeps": 0, "impacts": 0, "fallbacks": 0}
        tic = time.perf_counter()
        bar = tqdm(total=steps, desc="differentiable rollout", unit="step", disable=not progress, leave=False)
        for k0 in range(0, steps, seg):
            k1 = min(steps, k0 + seg)
            if checkpoint_every:
                outs = _Segment.apply(self, controls, tensors, k0, k1, info, x, v, params, *extra)
            else:
                outs = self._run(controls, tensors, k0, k1, x, v, params, info)
            X, V = outs[0], outs[1]
            xs.append(X)
            vs.append(V)
            x, v = X[-1], V[-1]
            bar.update(k1 - k0)
        bar.close()
        return Trajectory(torch.cat(xs), torch.cat(vs), self.dt, time.perf_counter() - tic, info["substeps"],
                          info["impacts"], info["fallbacks"])

    def _run(self, controls, tensors, k0, k1, x, v, params, info) -> tuple[torch.Tensor, torch.Tensor]:
        """Steps k0..k1-1 as one differentiable graph: positions and velocities [k1-k0, N, 3]."""
        X, V = [], []
        for k in range(k0, k1):
            force, wind, targets = self._step_inputs(k, x, v, controls, tensors)
            tapes: list = []
            x, v = differentiable_step(self.ctx, x, v, params, k * self.dt, self.dt, force, wind, targets, tapes=tapes)
            info["substeps"] += len(tapes)
            info["impacts"] += sum(t.impacts for t in tapes)
            info["fallbacks"] += sum(t.fallback for t in tapes)
            X.append(x)
            V.append(v)
        return torch.stack(X), torch.stack(V)


class _Segment(torch.autograd.Function):
    """Checkpointed segment: forward without a graph, backward re-runs the segment with one
    and differentiates it."""

    @staticmethod
    def forward(ctx, sim: DiffSimulator, controls: Controls, tensors: dict, k0: int, k1: int, info: dict, x, v, params, *extra):
        ctx.sim, ctx.controls, ctx.tensors, ctx.k0, ctx.k1 = sim, controls, tensors, k0, k1
        ctx.save_for_backward(x, v, params, *extra)
        with torch.no_grad():
            X, V = sim._run(controls, tensors, k0, k1, x, v, params, info)
        return X, V

    @staticmethod
    def backward(ctx, gX, gV):
        x, v, params, *extra = ctx.saved_tensors
        sim = ctx.sim
        sim.solver.set_fabric(sim.fabric.with_parameters(params.detach()))
        names = list(ctx.tensors)
        with torch.enable_grad():
            xl, vl, pl = (t.detach().requires_grad_() for t in (x, v, params))
            tensors = {k: t.detach().requires_grad_() for k, t in zip(names, extra)}
            policy_params = extra[len(names):]  # a policy computes with its own parameters
            X, V = sim._run(ctx.controls, tensors, ctx.k0, ctx.k1, xl, vl, pl, {"substeps": 0, "impacts": 0, "fallbacks": 0})
            leaves = [xl, vl, pl] + list(tensors.values()) + list(policy_params)
            grads = torch.autograd.grad((X, V), leaves, (gX, gV), allow_unused=True)
        return (None,) * 6 + tuple(grads)
