"""The run loop: the one place where a simulation's time advances (`solver.step`), and
the home of the policies every run shares.

`steps(...)` yields a `StepRecord` after every step, for callers that interleave their own
work with the simulation (time-parallel segments report progress between steps);
`advance(...)` takes one step for algorithms that step from states of their own.
`run(...)` drives `steps` to an end step or time with observers - callables that see every
record and may stop the run or end it with an error - and returns the totals:

    outcome = run(solver, state, dt, until=200, observers=[frames, SettleTest(0.02, after=40)])

The policies:
- per step (options of `steps` and `run`): a step length that may change over the run
  (`dt` a function), `before_step` (the cloth carried along by a body changing shape),
  `after_step` (damping), `FlungRedo` (a step that flings the cloth is redone from rest);
- observers: `FrameRecorder` (frame capture), `SettleTest` (every vertex slow),
  `RestDrift` (static equilibrium: the motion over a window of steps), `FailSafeLimit`
  (too many rigid fail-safe steps, or a frozen streak of them), `TopSpeed` (the fastest
  vertex, optionally a ceiling), `StepLog` (what the steps took);
- `TimeLimit`: the run's wall-clock budget, checked between steps.

Inputs that change during a run (a wind gust, a stitch stiffness ramp) come in as a
`Control` per step (`control=lambda step, t: Control(...)`), never by editing the model.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from tryon.errors import SimulationError
from tryon.sim.integrator import ImplicitEulerSolver, StepStats
from tryon.sim.model import ClothState, Control

ControlFn = Callable[[int, float], Control | None]  # (step about to run, its start time) -> inputs
StepSizeFn = Callable[[int, float], float]  # (step about to run, its start time) -> dt
Observer = Callable[["StepRecord"], bool | None]  # True stops the run after this step
StateFilter = Callable[[ClothState], ClothState]
BeforeStep = Callable[[int, ClothState], ClothState]  # (step about to run, state) -> the state it starts from


@dataclass
class StepRecord:
    """One finished step: its number (counted from the run's step 0), the new state, the
    solver's statistics, its wall time (the `before_step` move included), its length and the state it started from. A step
    redone because it flung the cloth (`FlungRedo`) has several solver steps (`attempts`,
    merged in `stats`) and says what happened in `flung`."""

    step: int
    state: ClothState
    stats: StepStats
    seconds: float
    dt: float = 0.0
    before: ClothState | None = None
    attempts: tuple[StepStats, ...] = ()
    flung: dict | None = None


@dataclass
class RunOutcome:
    """Where a run ended and what it took."""

    state: ClothState
    step: int
    totals: StepStats = field(default_factory=StepStats)
    retried_steps: int = 0
    wall_s: float = 0.0


def _fastest(state: ClothState) -> np.ndarray:
    v = state.v.numpy()
    return np.linalg.norm(v, axis=1) if len(v) else np.zeros(0)


@dataclass
class FlungRedo:
    """A step that leaves a vertex faster than `limit` m/s has been flung by a failed
    solve or collision response (slow motion such as draping never moves cloth that fast):
    it is redone from its start without its velocities, in `halves` steps of dt / halves
    (so is a step that left a velocity not a number). A redo that is flung too raises
    `SimulationError` with `explain(before, redone, speeds)`."""

    limit: float
    halves: int = 2
    explain: Callable[[ClothState, ClothState, np.ndarray], str] | None = None

    def redo(self, solver: ImplicitEulerSolver, before: ClothState, stepped: ClothState, dt: float, k: int,
             control: ControlFn | Control | None, attempts: list[StepStats]) -> tuple[ClothState, dict | None]:
        speeds = _fastest(stepped)
        if not len(speeds) or speeds.max() <= self.limit:  # NaN speeds compare False: redone
            return stepped, None
        flung = {"t": round(before.t, 4), "speed_m_s": round(float(speeds.max()), 2),
                 "vertices": np.argsort(-np.nan_to_num(speeds, nan=np.inf))[:5].tolist()}
        state = ClothState(before.x, torch.zeros_like(before.v), before.t)
        for _ in range(self.halves):
            state, stats = solver.step(state, dt / self.halves, _inputs(control, k, state.t))
            attempts.append(stats)
        speeds = _fastest(state)
        if not speeds.max() <= self.limit:  # a NaN speed is not a recovery
            why = self.explain(before, state, speeds) if self.explain else (
                f"at t={before.t:.2f}s the cloth moves at {speeds.max():.1f} m/s even after redoing the step in "
                f"{self.halves} parts from rest (at most {self.limit} m/s is plausible)")
            raise SimulationError(why)
        flung["recovered_speed_m_s"] = round(float(speeds.max()), 3)
        return state, flung


def _inputs(control: ControlFn | Control | None, k: int, t: float) -> Control | None:
    return control(k, t) if callable(control) else control


def _merged(attempts: list[StepStats]) -> StepStats:
    if len(attempts) == 1:
        return attempts[0]
    total = StepStats()
    for a in attempts:
        total.merge(a)
    return total


def steps(solver: ImplicitEulerSolver, state: ClothState, dt: float | StepSizeFn, start: int = 0, stop: int | None = None,
          control: ControlFn | Control | None = None, after_step: StateFilter | None = None,
          before_step: BeforeStep | None = None, redo_flung: FlungRedo | None = None) -> Iterator[StepRecord]:
    """Step `state` from step `start` until step `stop` (None: until the consumer stops
    iterating), yielding a record after each. `dt` is a length or a function of the step
    and its start time. `before_step` may move the state before a step (cloth carried
    along with a body changing shape); `after_step` may replace the new state (e.g. damp
    its velocities while a garment settles) before anyone sees it; `redo_flung` redoes a
    step that flung the cloth."""
    k = start
    while stop is None or k < stop:
        tic = time.perf_counter()
        if before_step is not None:
            state = before_step(k, state)
        h = dt(k, state.t) if callable(dt) else dt
        before = state
        state, stats = solver.step(state, h, _inputs(control, k, state.t))
        attempts = [stats]
        flung = None
        if redo_flung is not None:
            state, flung = redo_flung.redo(solver, before, state, h, k, control, attempts)
        if after_step is not None:
            state = after_step(state)
        k += 1
        yield StepRecord(k, state, _merged(attempts), time.perf_counter() - tic, h, before, tuple(attempts), flung)


def advance(solver: ImplicitEulerSolver, state: ClothState, dt: float, control: Control | None = None) -> StepRecord:
    """One step from `state`, as the loop takes it: for algorithms that step from states of
    their own making (the time-parallel coarse run, the recovery iterations)."""
    return next(steps(solver, state, dt, control=control))


@dataclass
class TimeLimit:
    """A run's wall-clock budget, checked between steps: past it, `SimulationError` with
    `explain(last record)`."""

    seconds: float
    explain: Callable[[StepRecord], str] | None = None

    def error(self, rec: StepRecord) -> SimulationError:
        why = self.explain(rec) if self.explain else (
            f"the run passed its time limit of {self.seconds:g} s at t={rec.state.t:.2f}s after {rec.step} steps")
        return SimulationError(why)


def run(solver: ImplicitEulerSolver, state: ClothState, dt: float | StepSizeFn, until: int | None, start: int = 0,
        observers: Sequence[Observer] = (), control: ControlFn | Control | None = None,
        after_step: StateFilter | None = None, progress: str | None = None,
        outcome: RunOutcome | None = None, before_step: BeforeStep | None = None,
        redo_flung: FlungRedo | None = None, until_time: float | None = None, time_limit: TimeLimit | None = None,
        total: int | None = None) -> RunOutcome:
    """Advance from step `start` to step `until` (None: no step bound), or until the
    simulated time reaches `until_time`, or until an observer returns True, and return the
    outcome. Observers see every step in order; one may raise to end the run with an error.
    `time_limit` is checked after them, on every step but one an observer ended the run on. `progress` names a progress bar (None: no bar) of
    `total` steps (default `until`). A resumed run passes the `outcome` it had reached so
    that the totals count the whole run."""
    outcome = outcome or RunOutcome(state, start)
    wall0 = time.perf_counter() - outcome.wall_s
    bar = tqdm(total=total or until, initial=start, desc=progress or "", unit="step", disable=progress is None,
               leave=False)
    try:
        if until_time is not None and state.t >= until_time - 1e-9:
            return outcome
        for rec in steps(solver, state, dt, start, until, control, after_step, before_step, redo_flung):
            outcome.state, outcome.step = rec.state, rec.step
            outcome.totals.merge(rec.stats)
            outcome.retried_steps += int(rec.stats.retried)
            bar.update(1)
            outcome.wall_s = time.perf_counter() - wall0
            stop = [bool(obs(rec)) for obs in observers]  # every observer sees every step
            if any(stop):  # an observer's end (the cloth at rest) is in time
                break
            if time_limit is not None and time.perf_counter() - wall0 > time_limit.seconds:
                raise time_limit.error(rec)  # the last step too, however the run ends
            if until_time is not None and rec.state.t >= until_time - 1e-9:
                break
    finally:
        bar.close()
        outcome.wall_s = time.perf_counter() - wall0
    return outcome


class FrameRecorder:
    """Keeps the state every `every` steps and at step `last` (positions and times)."""

    def __init__(self, every: int, last: int, first: ClothState | None = None):
        self.every, self.last = every, last
        self.positions: list[np.ndarray] = [] if first is None else [first.x.numpy().copy()]
        self.times: list[float] = [] if first is None else [first.t]

    def __call__(self, rec: StepRecord) -> bool:
        if rec.step % self.every == 0 or rec.step == self.last:
            self.positions.append(rec.state.x.numpy().copy())
            self.times.append(rec.state.t)
        return False


class SettleTest:
    """Stops the run once no vertex moves faster than `rest_speed` (m/s), from step
    `after` on: the cloth is at rest. `speed` is the fastest vertex's speed after the
    latest step."""

    def __init__(self, rest_speed: float, after: int = 0):
        self.rest_speed, self.after = rest_speed, after
        self.speed = float("inf")
        self.settled = False

    def __call__(self, rec: StepRecord) -> bool:
        v = rec.state.v.numpy()
        self.speed = float(np.linalg.norm(v, axis=1).max()) if len(v) else 0.0
        self.settled = rec.step >= self.after and self.speed <= self.rest_speed
        return self.settled


class RestDrift:
    """Static equilibrium: stops the run once, from time `after_t` on and on a step that
    did not need the fail-safe, every vertex's mean velocity over the last `window` steps
    (its displacement over the window's time) is below `rest_speed` (m/s). A vertex
    chattering in place against an obstacle does not move on; cloth still sliding or
    swinging does. `drift` is the latest such speed (inf before the window is full)."""

    def __init__(self, window: int, rest_speed: float, after_t: float = 0.0):
        self.rest_speed, self.after_t = rest_speed, after_t
        self._window: deque = deque(maxlen=window + 1)
        self.drift = float("inf")
        self.settled = False

    def __call__(self, rec: StepRecord) -> bool:
        self._window.append((rec.state.t, rec.state.x.numpy().copy()))
        if len(self._window) == self._window.maxlen:
            (t0, x0), (t1, x1) = self._window[0], self._window[-1]
            self.drift = float(np.linalg.norm(x1 - x0, axis=1).max()) / (t1 - t0)
        self.settled = rec.state.t >= self.after_t and self.drift < self.rest_speed and not rec.stats.fallback
        return self.settled


class FailSafeLimit:
    """Ends a run that keeps needing the rigid impact-zone fail-safe, which freezes cloth
    where it was: `streak` steps in a row that needed it and moved no vertex farther than
    `frozen` m, or `total` solver steps that needed it in all (each costs many times a
    normal step). Raises `error(explain(kind, record, count))`, kind "streak" or "total"."""

    def __init__(self, total: int | None = None, streak: int | None = None, frozen: float = 1e-5,
                 explain: Callable[[str, StepRecord, int], str] | None = None,
                 error: type[Exception] = SimulationError):
        self.total, self.streak_limit, self.frozen = total, streak, frozen
        self.explain, self.error = explain, error
        self.count = 0
        self.streak = 0

    def __call__(self, rec: StepRecord) -> bool:
        self.count += sum(int(a.fallback) for a in rec.attempts or (rec.stats,))
        if self.streak_limit is not None:
            moved = float(np.abs(rec.state.x.numpy() - rec.before.x.numpy()).max()) if rec.before is not None else 1.0
            self.streak = self.streak + 1 if rec.stats.fallback and moved < self.frozen else 0
            if self.streak >= self.streak_limit:
                raise self.error(self._why("streak", rec, self.streak))
        if self.total is not None and self.count >= self.total:
            raise self.error(self._why("total", rec, self.count))
        return False

    def _why(self, kind: str, rec: StepRecord, count: int) -> str:
        if self.explain is not None:
            return self.explain(kind, rec, count)
        if kind == "streak":
            return f"the rigid fail-safe froze the cloth {count} steps in a row by t={rec.state.t:.2f} s"
        return f"the collision response needed the rigid fail-safe {count} times by t={rec.state.t:.2f} s"


class TopSpeed:
    """The fastest vertex of the run so far (`fastest`, m/s) and of the latest step
    (`speeds`); with `limit`, raises `error(explain(record, speed))` past it."""

    def __init__(self, limit: float | None = None, explain: Callable[[StepRecord, float], str] | None = None,
                 error: type[Exception] = SimulationError):
        self.limit, self.explain, self.error = limit, explain, error
        self.fastest = 0.0
        self.speeds = np.zeros(0)

    def __call__(self, rec: StepRecord) -> bool:
        self.speeds = _fastest(rec.state)
        speed = float(self.speeds.max()) if len(self.speeds) else 0.0
        self.fastest = max(self.fastest, speed)
        if self.limit is not None and speed > self.limit:
            why = self.explain(rec, speed) if self.explain else f"the cloth moved at {speed:.1f} m/s at t={rec.state.t:.2f} s"
            raise self.error(why)
        return False


class StepLog:
    """What a run's steps took: steps, solver steps retried with substeps and solver
    steps that needed the fail-safe (a redone step counts each of its attempts), the
    slowest step (s) and the flung steps redone (`FlungRedo`)."""

    def __init__(self) -> None:
        self.steps = 0
        self.retried = 0
        self.failsafe = 0
        self.slowest_s = 0.0
        self.flung: list[dict] = []

    def __call__(self, rec: StepRecord) -> bool:
        attempts = rec.attempts or (rec.stats,)
        self.steps += 1
        self.retried += sum(int(a.retried) for a in attempts)
        self.failsafe += sum(int(a.fallback) for a in attempts)
        self.slowest_s = max(self.slowest_s, rec.seconds)
        if rec.flung is not None:
            self.flung.append(rec.flung)
        return False
