"""Motion control through the differentiable simulator (`tryon control --example basket`).

The basket task (after Liang, Lin & Koltun 2019, sec. 5.3): a square cloth lies on a
table; forces on its four corners, applied for `FORCE_TIME` seconds, must lift it over a
wall and drop it into an open basket beyond (a box, or a hopper in the ``sloped``
variant). The score is the distance of the cloth's centre of mass at the end to the
basket's lowest centre point (the centre of the box floor, the hopper's apex), divided
by the cloth size (the diagonal of the square).

The loss is the squared distance of the centre of mass to `WAYPOINTS` (above the wall
half-way, above the basket at release, at the basket's lowest centre point at the end)
over the cloth size squared: the final distance alone pulls the cloth straight into the
wall.

Controllers, each optimised with Adam on gradients of that loss (safeguarded: a step
that makes the loss 25 % worse than the best returns to the best with half the rate):

* ``direct``: the corner forces themselves, piecewise constant over `INTERVAL` s,
  ``F = -m g / 4 + F_max tanh(u)`` (each corner carries a quarter of the weight, so
  ``u = 0`` holds the cloth still: the position after 3 s is very sensitive to any
  net force, and the controls are deviations from hovering);
* ``policy``: a two-layer network (tanh hidden layer) mapping the cloth state (centre of
  mass, its velocity, corner offsets, time) to the corner forces;
* ``point-mass`` baseline: the direct forces optimised for a point of the cloth's mass
  (no cloth, no obstacles), then applied to the cloth;
* ``sampling`` baseline: the same direct forces searched without gradients, by the
  cross-entropy method (generations of `SAMPLING_POPULATION` samples around a mean, the
  best `SAMPLING_ELITE` of each setting the next mean and spread), with as many cloth
  simulations as the gradient-trained controllers get.

The ``sloped`` variant replaces the box basket by a hopper of the same opening and rim
height whose four walls lean inwards down to a point at the box floor's height and centre
(an open, upside-down square pyramid, the scene format's ``pyramid``): cloth that lands
on a wall slides down it, and cloth trailing just past the near rim lands on the near
wall, where a box is open.
"""

from __future__ import annotations

from collections.abc import Callable

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from tryon.diff.rollout import Controls, DiffSimulator, Trajectory
from tryon.errors import TryonError
from tryon.io.atomic import atomic_output_dir, atomic_write, check_output_dir
from tryon.io.json_safe import dumps_json
from tryon.sim.mesh import grid_corner
from tryon.sim.scene import Scene, parse_scene

EXAMPLES = ("basket",)
MODES = ("direct", "policy", "point-mass", "sampling")
VARIANTS = ("flat", "sloped")
FORCE_TIME = 3.0  # s of corner forces
DROP_TIME = 1.0  # s of free fall after them
INTERVAL = 0.5  # s: direct forces are constant over each interval
LEARNING_RATES = {"direct": 0.03, "policy": 0.001}  # Adam moves every weight by ~lr: a network needs less
LR_DECAY = 0.97  # per iteration: late steps refine instead of throwing the cloth around
REVERT = 1.25  # a sample this much worse than the best restarts from the best
F_MAX = 0.02  # N per corner and axis on top of carrying a quarter of the weight each
CLOTH = 0.3  # m, side of the square cloth
TABLE_TOP = 0.5
BASKET_CENTER = (0.85, 0.0)
BASKET_FLOOR = 0.04
BASKET_HALF = 0.2
BASKET_WALL = 0.22  # height of the basket's walls (the hopper's rim) above its floor
HIDDEN = 32
SAMPLING_POPULATION = 6  # cross-entropy method: samples per generation
SAMPLING_ELITE = 2  # the best of each generation set the next mean and spread
SAMPLING_STD = 1.0  # initial spread of u (tanh units: about the full force range)
SAMPLING_MIN_STD = 0.05
# (time as a fraction of the force time, centre-of-mass position); the end of the run last
WAYPOINTS = ((0.5, (0.42, 0.0, 0.9)), (1.0, (BASKET_CENTER[0], BASKET_CENTER[1], 0.8)))


def basket_spec(resolution: int = 5, variant: str = "flat", dt: float = 0.025) -> dict:
    """Scene of the basket task: table, wall and an open basket, box-shaped (`flat`) or a
    hopper (`sloped`)."""
    if variant not in VARIANTS:
        raise TryonError(f"unknown basket variant {variant!r}; choose one of {', '.join(VARIANTS)}")
    bx, by = BASKET_CENTER
    h, wall_h = BASKET_HALF, BASKET_WALL
    obstacles = [
        {"type": "box", "name": "table", "center": [0.0, 0.0, TABLE_TOP / 2], "size": [0.5, 0.5, TABLE_TOP]},
        {"type": "box", "name": "wall", "center": [0.42, 0.0, 0.3], "size": [0.04, 0.8, 0.6]},
    ]
    if variant == "flat":
        mid = BASKET_FLOOR + wall_h / 2
        obstacles += [
            {"type": "box", "name": "basket-floor", "center": [bx, by, BASKET_FLOOR / 2],
             "size": [2 * h, 2 * h, BASKET_FLOOR]},
            {"type": "box", "name": "basket-near", "center": [bx - h, by, mid], "size": [0.02, 2 * h, wall_h]},
            {"type": "box", "name": "basket-far", "center": [bx + h, by, mid], "size": [0.02, 2 * h, wall_h]},
            {"type": "box", "name": "basket-left", "center": [bx, by - h, mid], "size": [2 * h, 0.02, wall_h]},
            {"type": "box", "name": "basket-right", "center": [bx, by + h, mid], "size": [2 * h, 0.02, wall_h]},
        ]
    else:  # sloped: a hopper with the same opening and rim height, its walls meeting at the floor's centre
        obstacles.append({"type": "pyramid", "name": "basket-hopper", "apex": [bx, by, BASKET_FLOOR],
                          "rim_size": 2 * h, "height": wall_h})
    return {
        "name": f"basket-{variant}", "dt": dt, "duration": FORCE_TIME + DROP_TIME, "frame_time": 0.1,
        "cloth": {"grid": {"resolution": [resolution, resolution], "size": [CLOTH, CLOTH],
                           "origin": [-CLOTH / 2, -CLOTH / 2, TABLE_TOP + 0.006]}, "fabric": "gray-interlock"},
        "obstacles": obstacles,
        "collision": {"friction": 0.3, "self_collision": False},
    }


@dataclass
class ControlResult:
    """One controller's outcome on one variant."""

    mode: str
    variant: str
    distance_over_size: float
    landed_inside: bool
    samples: int
    cloth_simulations: int
    wall_s: float
    history: list = field(default_factory=list)
    trajectory: np.ndarray | None = None

    def summary(self) -> dict:
        return {"mode": self.mode, "variant": self.variant, "final_distance_over_size": self.distance_over_size,
                "landed_inside": self.landed_inside, "samples": self.samples,
                "cloth_simulations": self.cloth_simulations, "wall_s": self.wall_s,
                "loss_history": self.history}


class BasketTask:
    """Simulator, corners, target and score of the basket task."""

    def __init__(self, resolution: int = 5, variant: str = "flat", dt: float = 0.025):
        self.variant = variant
        self.scene: Scene = parse_scene(basket_spec(resolution, variant, dt))
        m = self.scene.model
        self.sim = DiffSimulator(m, self.scene.dt)
        names = ("bottom-left", "bottom-right", "top-left", "top-right")
        self.corners = torch.tensor([grid_corner((resolution, resolution), c) for c in names])
        self.steps = int(round((FORCE_TIME + DROP_TIME) / self.scene.dt))
        self.force_steps = int(round(FORCE_TIME / self.scene.dt))
        self.mass = m.mass().detach()
        self.total_mass = float(self.mass.sum())
        self.size = m.mesh.size()
        self.target = torch.tensor([BASKET_CENTER[0], BASKET_CENTER[1], BASKET_FLOOR], dtype=torch.float64)
        self.x0 = m.initial_state().x
        self.hover = -self.total_mass * m.gravity / 4  # N per corner that carries the weight

    def com(self, x: torch.Tensor) -> torch.Tensor:
        return (self.mass[:, None] * x).sum(-2) / self.total_mass

    def rollout(self, controls: Controls) -> Trajectory:
        return self.sim.rollout(self.steps, controls=controls)

    def waypoint_steps(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Step indices (into a trajectory with its initial state) and positions of the
        waypoints, the final target last."""
        steps = [int(round(f * self.force_steps)) for f, _ in WAYPOINTS] + [self.steps]
        points = [torch.tensor(p, dtype=torch.float64) for _, p in WAYPOINTS] + [self.target]
        return torch.tensor(steps), torch.stack(points)

    def loss(self, traj: Trajectory) -> torch.Tensor:
        steps, points = self.waypoint_steps()
        return ((self.com(traj.x[steps]) - points) ** 2).sum() / self.size**2

    def score(self, x_final: torch.Tensor) -> tuple[float, bool]:
        """Final COM distance to the basket's lowest centre point / cloth size, and
        whether the cloth's centre lies within the rim's footprint below its top."""
        c = self.com(x_final.detach())
        ratio = float((c - self.target).norm()) / self.size
        inside = bool((c[:2] - self.target[:2]).abs().max() < BASKET_HALF and c[2] < BASKET_FLOOR + BASKET_WALL)
        return ratio, inside


# --------------------------------------------------------------------------- controllers


def interval_forces(u: torch.Tensor, task: BasketTask) -> torch.Tensor:
    """Per-step corner forces [steps, 4, 3] from interval parameters u [K, 4, 3]."""
    per = max(1, int(round(INTERVAL / task.scene.dt)))
    f = task.hover + F_MAX * torch.tanh(u).repeat_interleave(per, 0)[: task.force_steps]
    pad = torch.zeros(task.steps - len(f), 4, 3, dtype=f.dtype)
    return torch.cat([f, pad])


def _n_intervals(task: BasketTask) -> int:
    per = max(1, int(round(INTERVAL / task.scene.dt)))
    return -(-task.force_steps // per)


class CornerPolicy(torch.nn.Module):
    """Two-layer network: cloth state -> corner forces (N), zero after the force time."""

    def __init__(self, task: BasketTask, hidden: int = HIDDEN, seed: int = 0):
        super().__init__()
        self.task = task
        with torch.random.fork_rng():
            torch.manual_seed(seed)  # reproducible runs without touching the caller's generator
            self.net = torch.nn.Sequential(torch.nn.Linear(19, hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, 12)).double()
        torch.nn.init.zeros_(self.net[2].weight)
        torch.nn.init.zeros_(self.net[2].bias)

    def forward(self, k: int, x: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        t = self.task
        if k >= t.force_steps:
            return torch.zeros(4, 3, dtype=x.dtype)
        c, cv = t.com(x), t.com(v)
        rel = (x[t.corners] - c).reshape(-1) / CLOTH
        feats = torch.cat([c - t.target, cv, rel, torch.tensor([k / t.force_steps], dtype=x.dtype)])
        return t.hover + F_MAX * torch.tanh(self.net(feats)).reshape(4, 3)


def point_mass_forces(task: BasketTask, iterations: int = 500) -> tuple[torch.Tensor, int]:
    """Interval parameters optimised for a point of the cloth's mass (no cloth, no
    obstacles but a floor at the basket's lowest point). Semi-implicit Euler from rest ends at
    p_T = p_0 + dt^2 sum_k (T - k) a_k, so each of the `iterations` point-mass simulations
    is one weighted sum. Returns (u, simulations)."""
    u = torch.zeros(_n_intervals(task), 4, 3, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([u], lr=0.05)
    dt, T = task.scene.dt, task.steps
    steps, points = task.waypoint_steps()
    j = torch.arange(T, dtype=torch.float64)
    lever = dt * dt * (steps[:, None] - j[None]).clamp(min=0.0)  # [waypoints, T]
    p0 = task.com(task.x0)
    for _ in range(iterations):
        acc = interval_forces(u, task).sum(1) / task.total_mass + task.scene.model.gravity
        p = p0 + lever @ acc
        p = torch.cat([p[:, :2], p[:, 2:].clamp(min=BASKET_FLOOR)], 1)  # the basket's bottom stops it
        loss = ((p - points) ** 2).sum() / task.size**2
        opt.zero_grad()
        loss.backward()
        opt.step()
    return u.detach(), iterations


def _controller(task: BasketTask, mode: str):
    """Trainable tensors and a function making the rollout's `Controls` from them."""
    if mode == "direct":
        u = torch.zeros(_n_intervals(task), 4, 3, dtype=torch.float64, requires_grad=True)
        return [u], lambda: Controls(forces=interval_forces(u, task), force_vertices=task.corners)
    policy = CornerPolicy(task)
    return list(policy.parameters()), lambda: Controls(policy=policy, force_vertices=task.corners)


def optimise(task: BasketTask, mode: str, iterations: int, lr: float | None = None, progress: bool = False) -> ControlResult:
    """Adam on the rollout loss for the `direct` or `policy` controller, safeguarded: a
    sample whose loss exceeds `REVERT` x the best so far (a step that threw the cloth
    into the wall) returns to the best parameters with half the learning rate."""
    tic = time.perf_counter()
    params, controls = _controller(task, mode)
    opt = torch.optim.Adam(params, lr=LEARNING_RATES[mode] if lr is None else lr)
    best, history = (float("inf"), None), []
    best_loss, best_params = float("inf"), [p.detach().clone() for p in params]
    bar = tqdm(range(iterations), desc=f"control ({mode}, {task.variant})", unit="rollout", disable=not progress, leave=False)
    for _ in bar:
        traj = task.rollout(controls())
        loss = task.loss(traj)
        value = float(loss.detach())
        ratio, _ = task.score(traj.x[-1])
        history.append(value)
        if ratio < best[0]:
            best = (ratio, traj.x.detach().numpy())
        bar.set_postfix(distance=f"{ratio:.3f}")
        if value > REVERT * best_loss:
            with torch.no_grad():
                for p, keep in zip(params, best_params):
                    p.copy_(keep)
            for group in opt.param_groups:
                group["lr"] *= 0.5
            opt.state.clear()
            continue
        if value < best_loss:
            best_loss, best_params = value, [p.detach().clone() for p in params]
        opt.zero_grad()
        loss.backward()
        opt.step()
        for group in opt.param_groups:
            group["lr"] *= LR_DECAY
    ratio, inside = task.score(torch.from_numpy(best[1][-1]))
    return ControlResult(mode, task.variant, ratio, inside, iterations, iterations, time.perf_counter() - tic,
                         history, best[1])


def sample_search(task: BasketTask, samples: int, seed: int = 0, progress: bool = False) -> ControlResult:
    """The cross-entropy method over the direct controller's u (module docstring): forward
    simulations only, `samples` of them; the result is the best sample's."""
    if samples < 1:
        raise TryonError(f"the sampling baseline needs at least 1 sample, got {samples}")
    tic = time.perf_counter()
    rng = np.random.default_rng(seed)
    shape = (_n_intervals(task), 4, 3)
    mean, std = np.zeros(shape), np.full(shape, SAMPLING_STD)
    best, history, done = (float("inf"), None), [], 0
    bar = tqdm(total=samples, desc=f"control (sampling, {task.variant})", unit="rollout", disable=not progress, leave=False)
    while done < samples:
        batch = [mean + std * rng.standard_normal(shape) for _ in range(min(SAMPLING_POPULATION, samples - done))]
        losses = []
        for u in batch:
            with torch.no_grad():
                traj = task.rollout(Controls(forces=interval_forces(torch.from_numpy(u), task), force_vertices=task.corners))
                losses.append(float(task.loss(traj)))
            ratio, _ = task.score(traj.x[-1])
            if ratio < best[0] or best[1] is None:
                best = (ratio, traj.x.numpy())
            history.append(losses[-1])
            bar.update(1)
            bar.set_postfix(distance=f"{best[0]:.3f}")
        done += len(batch)
        elite = np.stack([batch[i] for i in np.argsort(losses)[:SAMPLING_ELITE]])
        mean, std = elite.mean(0), np.maximum(elite.std(0), SAMPLING_MIN_STD)
    bar.close()
    ratio, inside = task.score(torch.from_numpy(best[1][-1]))
    return ControlResult("sampling", task.variant, ratio, inside, samples, samples, time.perf_counter() - tic, history,
                         best[1])


def run_point_mass(task: BasketTask) -> ControlResult:
    tic = time.perf_counter()
    u, sims = point_mass_forces(task)
    with torch.no_grad():
        traj = task.rollout(Controls(forces=interval_forces(u, task), force_vertices=task.corners))
    ratio, inside = task.score(traj.x[-1])
    return ControlResult("point-mass", task.variant, ratio, inside, sims, 1, time.perf_counter() - tic, [],
                         traj.x.numpy())


# --------------------------------------------------------------------------- outputs


def run_control(example: str, out: str, modes: tuple[str, ...] = MODES, variants: tuple[str, ...] = VARIANTS,
                iterations: int = 30, resolution: int = 5, dt: float = 0.025, lr: float | None = None,
                progress: bool = True, force: bool = False,
                preview: Callable[[Path, Scene, np.ndarray], None] | None = None) -> dict:
    """`tryon control --example basket`: optimise each controller on each variant, write
    report.json and a preview GIF per variant (of its best controller) into `out`."""
    if example not in EXAMPLES:
        raise TryonError(f"unknown control example {example!r}; choose one of {', '.join(EXAMPLES)}")
    bad = [m for m in modes if m not in MODES]
    if bad:
        raise TryonError(f"unknown control mode(s) {bad}; choose from {', '.join(MODES)}")
    if iterations < 1:
        raise TryonError(f"--iterations must be at least 1, got {iterations}")
    check_output_dir(out, force=force)
    report = {"example": example, "force_time_s": FORCE_TIME, "drop_time_s": DROP_TIME, "resolution": resolution,
              "dt": dt, "iterations": iterations, "results": []}
    previews: list[tuple[str, BasketTask, np.ndarray]] = []
    for variant in variants:
        task = BasketTask(resolution, variant, dt)
        results = []
        for mode in modes:
            if mode == "point-mass":
                res = run_point_mass(task)
            elif mode == "sampling":
                res = sample_search(task, iterations, progress=progress)
            else:
                res = optimise(task, mode, iterations, lr, progress)
            results.append(res)
            report["results"].append(res.summary())
        best = min(results, key=lambda r: r.distance_over_size)
        previews.append((f"preview_{variant}.gif", task, best.trajectory))
    report["cloth_size_m"] = previews[0][1].size if previews else None
    with atomic_output_dir(out, force=force) as tmp:
        for name, task, traj in previews if preview is not None else ():  # e.g. sim_pictures.trajectory_gif
            preview(tmp / name, task.scene, traj)
        with atomic_write(tmp / "report.json") as fh:
            fh.write(dumps_json(report, indent=2))
    return report
