"""Detail recovery at a segment start (Liang & Lin, SCA 2018, Algorithm 3).

The coarse run gives the cloth's state at the segment start t_s only at coarse
resolution; its upsampling u(X_c) is smooth, and starting the fine segment from it would
"pop" (wrinkles vanish and re-form). Recovery lets the fine dynamics grow the detail while
the coarse-scale shape stays on the coarse trajectory. Starting from x = u(X_c(t_s)),
v = u(V_c(t_s)), it alternates

1. one fine step of dt from t_s with tracking constraints R x = X_c(t_s + dt) (TRACKS,
   Bergou et al. 2007; enforced as the mass-weighted projection x + U (X_c - R x) on
   positions and velocities, see `Hierarchy.track`), and
2. subtracting the upsampled coarse change u(X_c(t_s + dt) - X_c(t_s)) (and likewise for
   velocities), which takes the state back to t_s while keeping the fine detail,

for at most n = ceil(c0 sqrt(m / xi) / dt) iterations (c0 = 10, m the areal density, xi
the norm of the fabric's membrane stiffness at rest; sqrt(m / xi) is the time a membrane
wave needs to cross a metre of cloth), or until the RMS vertex change of an iteration
falls below `tolerance` times the cloth size. Vertices the upsampled shape puts into an
obstacle are pushed out (`push_outside`); when the start is free of crossings, the
projection and the step back to t_s are moved to as collision-handled motions
(`collision_free_move`: the simulator's CCD and impact zones, obstacles moving back to
t_s), so that no iteration puts cloth through cloth or body; the recovered state is
made free of cloth-obstacle crossings (`clear_of_obstacles`) so that the fine segment's
collision handling can start from it. Detail velocities are dropped
(`keep_detail_velocity` = 0): the recovered state moves with the coarse velocity.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from tryon.errors import SimulationError, TryonError
from tryon.fabric.base import Fabric
from tryon.parallel.hierarchy import Hierarchy
from tryon.sim.collision import stitch_alias
from tryon.sim.geometry import count_intersections, edge_face_intersections
from tryon.sim.geometry import push_outside as surface_push_outside
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.loop import advance
from tryon.sim.model import ClothState


@dataclass
class RecoveryOptions:
    """`c0` scales the iteration limit; `tolerance` is the stopping change as a fraction of
    the cloth size; `max_iterations` overrides the c0 limit; `enabled=False` starts fine
    segments from the plain upsampled coarse state (for comparisons)."""

    c0: float = 10.0
    tolerance: float = 1e-3
    max_iterations: int | None = None
    enabled: bool = True
    keep_detail_velocity: float = 0.0

    def validate(self) -> None:
        if self.c0 <= 0 or self.tolerance <= 0:
            raise TryonError(f"detail recovery needs c0 > 0 and tolerance > 0, got c0={self.c0}, tolerance={self.tolerance}")
        if self.max_iterations is not None and self.max_iterations < 0:
            raise TryonError(f"detail recovery max_iterations must be >= 0, got {self.max_iterations}")


@dataclass
class RecoveryReport:
    iterations: int = 0
    limit: int = 0
    converged: bool = False
    changes: list[float] = field(default_factory=list)  # RMS vertex change per iteration (m)
    seconds: float = 0.0
    failed: str = ""
    stopped: str = ""  # why iterations ended early without failing
    detail_kept: float = 1.0  # mean fraction of the carried detail kept (`start_positions`)
    start: np.ndarray | None = None  # the fine positions recovery started from (u(X_c), cleared)


def stiffness_norm(fabric: Fabric) -> float:
    """xi: Euclidean norm (N/m) of the membrane stiffnesses (k0..k3) at zero strain."""
    k = fabric.stretching_stiffness(torch.zeros(1, 3, dtype=torch.float64))
    return float(torch.linalg.norm(k.detach().reshape(-1)))


def iteration_limit(fabric: Fabric, dt: float, c0: float = 10.0) -> int:
    """n = ceil(c0 sqrt(m / xi) / dt)."""
    m = float(fabric.density)
    xi = stiffness_norm(fabric)
    if m <= 0 or xi <= 0:
        raise TryonError(f"fabric {fabric.name}: detail recovery needs a positive density and stiffness")
    return max(1, math.ceil(c0 * math.sqrt(m / xi) / dt))


def coarse_edge_length(hier: Hierarchy) -> float:
    """Mean edge length (m) of the coarse cloth at rest."""
    mesh = hier.coarse.model.mesh
    e = mesh.edges.numpy()
    return float(np.linalg.norm(mesh.x.numpy()[e[:, 0]] - mesh.x.numpy()[e[:, 1]], axis=1).mean())


GAPS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0)  # contact thicknesses tried until no cloth edge crosses an obstacle


def push_outside(hier: Hierarchy, x: np.ndarray, t: float, gap: float | None = None) -> np.ndarray:
    """Fine vertices that an upsampled coarse shape puts inside an obstacle or nearer than
    `gap` (default: the contact thickness; a coarse triangle is a chord of a curved body)
    moved out along the obstacle's normal to `gap`. Only points at most a coarse edge
    length deep move (deeper ones are behind an open obstacle surface, not in it)."""
    return _pushed(hier, x, t, [hier.fine.model.collision.thickness if gap is None else gap])[0]


def _pushed(hier: Hierarchy, x: np.ndarray, t: float, gaps: list[float], accept=None) -> tuple[np.ndarray, float]:
    """`tryon.sim.geometry.push_outside` against the fine level's obstacles at t, pins fixed."""
    model = hier.fine.model
    ob = model.obstacles.vertices_at(t)
    if len(ob) == 0 or not model.collision.enabled:
        return x, gaps[0]
    pinned = model.pinned.numpy() if len(model.pinned) else None
    out, _, used = surface_push_outside(x, ob, model.obstacles.faces, gaps, accept=accept,
                                        max_depth=coarse_edge_length(hier), fixed=pinned)
    return out, used


def obstacle_crossings(hier: Hierarchy, x: np.ndarray, t: float) -> int:
    """Cloth edges through obstacle faces and obstacle edges through cloth faces at t."""
    m = hier.fine.model
    ob = m.obstacles.vertices_at(t)
    if len(ob) == 0:
        return 0
    _, crossing = count_intersections(np.ascontiguousarray(x), m.faces.numpy(), m.edges.numpy(), ob, m.obstacles.faces,
                                      m.obstacles.edges, self_collision=False)
    return int(crossing)


def clear_of_obstacles(hier: Hierarchy, x: np.ndarray, t: float) -> tuple[np.ndarray, float]:
    """`push_outside` with the smallest gap (in contact thicknesses, `GAPS`) that leaves no
    cloth-obstacle crossing, so that collision handling can start from the state."""
    gaps = [k * hier.fine.model.collision.thickness for k in GAPS]
    return _pushed(hier, x, t, gaps, accept=lambda candidate: obstacle_crossings(hier, candidate, t) == 0)


def self_intersecting_vertices(hier: Hierarchy, x: np.ndarray) -> np.ndarray:
    """Fine vertices of cloth edges and faces that pass through each other (none when the
    fine level does not collide with itself)."""
    m = hier.fine.model
    if not (m.collision.enabled and m.collision.self_collision):
        return np.zeros(0, np.int64)
    edges, faces = m.edges.numpy(), m.faces.numpy()
    pairs = edge_face_intersections(np.ascontiguousarray(x, np.float64), edges, np.ascontiguousarray(x, np.float64),
                                    faces, True, stitch_alias(m.stitches, m.num_vertices))
    return np.unique(np.concatenate([edges[pairs[:, 0]].ravel(), faces[pairs[:, 1]].ravel()]))


def crossings(hier: Hierarchy, x: np.ndarray, t: float) -> int:
    """Fine vertices passing through the cloth (`self_intersecting_vertices`) plus
    cloth-obstacle crossings (`obstacle_crossings`) of the fine cloth at `x`, time `t`."""
    return len(self_intersecting_vertices(hier, x)) + obstacle_crossings(hier, x, t)


def _with_one_ring(faces: np.ndarray, vertices: np.ndarray, n: int) -> np.ndarray:
    mark = np.zeros(n, bool)
    mark[vertices] = True
    mark[faces[mark[faces].any(1)].ravel()] = True
    return np.flatnonzero(mark)


def collision_free_move(solver: ImplicitEulerSolver, x0: np.ndarray, x1: np.ndarray, t0: float,
                        t1: float) -> np.ndarray | None:
    """The move of the solver's cloth from x0 (free of intersections, obstacles at t0)
    towards x1 (obstacles at t1) with its collision response (continuous collision
    detection, impact zones): positions as close to x1 as the move allows without any
    cloth passing through cloth or obstacle; None if the response does not succeed."""
    obstacles = solver.model.obstacles
    x, report = solver.collision_response(x0, x1, obstacles.vertices_at(t0), obstacles.vertices_at(t1))
    return x if report.success and np.all(np.isfinite(x)) else None


def start_positions(hier: Hierarchy, xc: np.ndarray, t: float, push: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Fine positions u(X_c) (pinned vertices on their handles, with `push` moved out of the
    obstacles) and the fraction of the carried detail kept at each vertex. The detail was
    the fine cloth's at t = 0; carried to another pose it can put one cloth layer through
    another (at the armpits, say), which collision handling cannot start from: around
    such crossings it is halved, then dropped, until none are left (or no detail is)."""
    model = hier.fine.model
    n = model.num_vertices
    keep = np.ones(n)
    while True:
        x = hier.upsample_positions(xc, keep)
        if len(model.pinned):
            x[model.pinned.numpy()] = model.pin_targets(t).numpy()
        if push:
            x, _ = clear_of_obstacles(hier, x, t)
        if hier.detail is None:
            return x, keep
        crossing = self_intersecting_vertices(hier, x)
        ring = _with_one_ring(model.faces.numpy(), crossing, n) if len(crossing) else crossing
        if not len(ring) or not keep[ring].any():
            return x, keep
        keep[ring] = np.where(keep[ring] > 0.5, 0.5, 0.0)


def upsampled_state(hier: Hierarchy, xc: np.ndarray, vc: np.ndarray, t: float, push: bool = True) -> ClothState:
    """The fine state from a coarse one: `start_positions`, velocities u(V_c)."""
    x, _ = start_positions(hier, xc, t, push)
    return ClothState(torch.from_numpy(x), torch.from_numpy(hier.upsample(vc)), t)


def recover_details(
    solver: ImplicitEulerSolver,
    hier: Hierarchy,
    coarse_start: tuple[np.ndarray, np.ndarray],
    coarse_next: tuple[np.ndarray, np.ndarray],
    t: float,
    dt: float,
    options: RecoveryOptions | None = None,
) -> tuple[ClothState, RecoveryReport]:
    """Algorithm 3: the fine state at time t from the coarse states at t and t + dt."""
    options = options or RecoveryOptions()
    options.validate()
    model = hier.fine.model
    xc0, vc0 = coarse_start
    xc1, vc1 = coarse_next
    x, keep = start_positions(hier, xc0, t)
    state = ClothState(torch.from_numpy(x), torch.from_numpy(hier.upsample(vc0)), t)
    limit = options.max_iterations if options.max_iterations is not None else iteration_limit(model.fabric, dt, options.c0)
    report = RecoveryReport(limit=limit, start=x.copy())
    if not options.enabled or limit == 0:
        return state, report
    tic = time.perf_counter()
    dX = hier.upsample_positions(xc1, keep) - hier.upsample_positions(xc0, keep)
    dV = hier.upsample(vc1 - vc0)
    target = hier.coarse_part(xc1, keep)
    report.detail_kept = float(keep.mean())
    clean = not len(self_intersecting_vertices(hier, x))
    pinned = model.pinned.numpy()
    tol = options.tolerance * model.mesh.size()
    for _ in range(limit):
        try:
            stepped = advance(solver, state, dt).state
        except SimulationError as exc:
            report.failed = str(exc)
            break
        x1 = stepped.x.numpy()
        x = hier.track(x1, target)
        v = hier.track(stepped.v.numpy(), vc1)
        if len(pinned):
            x[pinned] = model.pin_targets(t + dt).numpy()
        if clean:  # move to the projection, then back to t, as collision-handled motions
            x = collision_free_move(solver, x1, x, t + dt, t + dt)
            x = collision_free_move(solver, x, x - dX, t + dt, t) if x is not None else None
            if x is None:
                report.stopped = "collision handling could not follow the tracking projection; kept the last iterate"
                break
        else:
            x = push_outside(hier, x - dX, t)
        v = v - dV
        if options.keep_detail_velocity < 1.0:
            v_coarse = hier.upsample(vc0)
            v = v_coarse + options.keep_detail_velocity * (v - v_coarse)
        change = float(np.sqrt(np.mean(np.sum((x - state.x.numpy()) ** 2, 1))))
        state = ClothState(torch.from_numpy(x), torch.from_numpy(v), t)
        report.iterations += 1
        report.changes.append(change)
        if change < tol:
            report.converged = True
            break
    if obstacle_crossings(hier, state.x.numpy(), t):
        x, _ = clear_of_obstacles(hier, state.x.numpy(), t)
        state = ClothState(torch.from_numpy(x), state.v, t)
    report.seconds = time.perf_counter() - tic
    return state, report


def oracle_recovery_errors(solver: ImplicitEulerSolver, hier: Hierarchy, states: np.ndarray, step: int,
                           options: RecoveryOptions | None = None) -> dict:
    """Detail recovery measured on its own: from the serial fine run's exact coarse-scale
    states R x(t_s), R v(t_s) and one step later (`states` [N+1, n, 3] every fine step;
    velocities as implicit Euler's position differences over dt), the relative curvature
    error against the serial state x(t_s) of the naive upsample (before) and of the
    recovered state (after). A time-parallel run's error adds the coarse predictor's
    coarse-scale error, which recovery by construction does not change."""
    from tryon.parallel.curvature import relative_curvature_error

    if not 1 <= step < len(states) - 1:
        raise TryonError(f"the oracle recovery needs serial states around step {step}")
    dt = hier.fine.dt
    t = step * dt
    v0, v1 = (states[step] - states[step - 1]) / dt, (states[step + 1] - states[step]) / dt
    start = (hier.coarse_state_of(states[step]), hier.restrict(v0))
    nxt = (hier.coarse_state_of(states[step + 1]), hier.restrict(v1))
    before = upsampled_state(hier, *start, t).x.numpy()
    state, report = recover_details(solver, hier, start, nxt, t, dt, options)
    model = hier.fine.model
    return {"step": step, "before": relative_curvature_error(model, before, states[step]),
            "after": relative_curvature_error(model, state.x.numpy(), states[step]), "iterations": report.iterations}
