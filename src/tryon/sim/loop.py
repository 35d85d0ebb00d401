"""The run loop: the one place where a simulation's time advances (`solver.step`).

`steps(...)` yields a `StepRecord` after every step, for callers that interleave their own
work with the simulation (time-parallel segments report progress between steps).
`run(...)` drives `steps` to an end step with observers - callables that see every record
and may stop the run (a settling test, a sewing test) - and returns the totals:

    outcome = run(solver, state, dt, until=200, observers=[frames, SettleTest(0.02, after=40)])

Inputs that change during a run (a wind gust, a stitch stiffness ramp) come in as a
`Control` per step (`control=lambda step, t: Control(...)`), never by editing the model.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from tryon.sim.integrator import ImplicitEulerSolver, StepStats
from tryon.sim.model import ClothState, Control

ControlFn = Callable[[int, float], Control | None]  # (step about to run, its start time) -> inputs
Observer = Callable[["StepRecord"], bool | None]  # True stops the run after this step
StateFilter = Callable[[ClothState], ClothState]


@dataclass
class StepRecord:
    """One finished step: its number (counted from the run's step 0), the new state, the
    solver's statistics and its wall time."""

    step: int
    state: ClothState
    stats: StepStats
    seconds: float


@dataclass
class RunOutcome:
    """Where a run ended and what it took."""

    state: ClothState
    step: int
    totals: StepStats = field(default_factory=StepStats)
    retried_steps: int = 0
    wall_s: float = 0.0


def steps(solver: ImplicitEulerSolver, state: ClothState, dt: float, start: int = 0, stop: int | None = None,
          control: ControlFn | Control | None = None, after_step: StateFilter | None = None) -> Iterator[StepRecord]:
    """Step `state` from step `start` until step `stop` (None: until the consumer stops
    iterating), yielding a record after each. `after_step` may replace the new state
    (e.g. damp its velocities while a garment settles) before anyone sees it."""
    k = start
    while stop is None or k < stop:
        inputs = control(k, state.t) if callable(control) else control
        tic = time.perf_counter()
        state, stats = solver.step(state, dt, inputs)
        seconds = time.perf_counter() - tic
        if after_step is not None:
            state = after_step(state)
        k += 1
        yield StepRecord(k, state, stats, seconds)


def run(solver: ImplicitEulerSolver, state: ClothState, dt: float, until: int, start: int = 0,
        observers: Sequence[Observer] = (), control: ControlFn | Control | None = None,
        after_step: StateFilter | None = None, progress: str | None = None,
        outcome: RunOutcome | None = None) -> RunOutcome:
    """Advance from step `start` to step `until` (or until an observer returns True) and
    return the outcome. `progress` names a progress bar (None: no bar). A resumed run
    passes the `outcome` it had reached so that the totals count the whole run."""
    outcome = outcome or RunOutcome(state, start)
    wall0 = time.perf_counter() - outcome.wall_s
    bar = tqdm(total=until, initial=start, desc=progress or "", unit="step", disable=progress is None, leave=False)
    try:
        for rec in steps(solver, state, dt, start, until, control, after_step):
            outcome.state, outcome.step = rec.state, rec.step
            outcome.totals.merge(rec.stats)
            outcome.retried_steps += int(rec.stats.retried)
            bar.update(1)
            outcome.wall_s = time.perf_counter() - wall0
            stop = [bool(obs(rec)) for obs in observers]  # every observer sees every step
            if any(stop):
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
