"""The run loop's policies (flung-step redo, fail-safe limits, rest by drift, time limit,
end time, a step length that changes, a state moved before each step) on a scripted
solver whose every step is known."""

import time

import numpy as np
import pytest
import torch

from tryon.errors import SimulationError
from tryon.sim.integrator import StepStats
from tryon.sim.loop import (FailSafeLimit, FlungRedo, FrameRecorder, RestDrift, StepLog, TimeLimit, TopSpeed, advance,
                            run)
from tryon.sim.model import ClothState


class Scripted:
    """Moves every vertex at `speed` (m/s) along x; step numbers in `fling` throw vertex 1
    at 80 m/s, those in `failsafe` end in the (frozen) fail-safe."""

    def __init__(self, speed=0.1, fling=(), failsafe=(), frozen=True, sleep=0.0):
        self.speed, self.fling, self.failsafe, self.frozen, self.sleep = speed, set(fling), set(failsafe), frozen, sleep
        self.calls = []

    def step(self, state, dt, control=None):
        n = len(self.calls)
        self.calls.append((round(state.t, 6), dt, control))
        time.sleep(self.sleep)
        v = torch.zeros_like(state.v)
        if not (n in self.failsafe and self.frozen):
            v[:, 0] = self.speed
        if n in self.fling:
            v[1, 0] = 80.0
        return ClothState(state.x + dt * v, v, state.t + dt), StepStats(substeps=1, fallback=n in self.failsafe)


def _start(n=4):
    return ClothState(torch.zeros(n, 3, dtype=torch.float64), torch.zeros(n, 3, dtype=torch.float64), 0.0)


def test_a_flung_step_is_redone_from_rest_in_halves_and_reported():
    solver = Scripted(fling={2})
    log = StepLog()
    out = run(solver, _start(), 0.01, until=5, observers=[log], redo_flung=FlungRedo(5.0))
    assert out.step == 5 and len(solver.calls) == 7  # step 3 took the flung try and two halves
    assert [c[1] for c in solver.calls[2:5]] == [0.01, 0.005, 0.005]
    assert log.flung == [{"t": 0.02, "speed_m_s": 80.0, "vertices": [1, 0, 2, 3], "recovered_speed_m_s": 0.1}]
    assert abs(out.state.t - 0.05) < 1e-12 and float(out.state.v.abs().max()) == pytest.approx(0.1)


def test_a_redo_that_is_flung_again_raises_with_the_explanation():
    solver = Scripted(fling={0, 1, 2})
    with pytest.raises(SimulationError, match="still flung at t=0.00"):
        run(solver, _start(), 0.01, until=3,
            redo_flung=FlungRedo(5.0, explain=lambda before, redone, speeds: f"still flung at t={before.t:.2f}"))


def test_a_step_that_leaves_no_number_is_redone_and_a_redo_that_does_raises():
    class NotANumber(Scripted):
        def __init__(self, nan):
            super().__init__()
            self.nan = nan

        def step(self, state, dt, control=None):
            new, stats = super().step(state, dt, control)
            if len(self.calls) - 1 in self.nan:
                new.v[2, 1] = float("nan")
            return new, stats

    out = run(NotANumber(nan={0}), _start(), 0.01, until=1, redo_flung=FlungRedo(5.0))
    assert np.isfinite(out.state.v.numpy()).all()
    with pytest.raises(SimulationError, match="even after redoing"):
        run(NotANumber(nan={0, 1, 2}), _start(), 0.01, until=1, redo_flung=FlungRedo(5.0))


def test_fail_safe_limits_count_frozen_streaks_and_totals():
    with pytest.raises(SimulationError, match="froze the cloth 3 steps in a row"):
        run(Scripted(failsafe={1, 2, 3}), _start(), 0.01, until=10, observers=[FailSafeLimit(streak=3)])
    # a fail-safe step that still moves the cloth breaks no streak, but counts towards the total
    guard = FailSafeLimit(total=4, streak=2)
    with pytest.raises(SimulationError, match="needed the rigid fail-safe 4 times by t=0.08"):
        run(Scripted(failsafe={1, 3, 5, 7}, frozen=False), _start(), 0.01, until=20, observers=[guard])
    assert guard.streak == 0
    # the total counts every solver step of a redone (flung) step
    guard = FailSafeLimit(total=10)
    run(Scripted(fling={0}, failsafe={0, 1, 2}, frozen=False), _start(), 0.01, until=1, observers=[guard],
        redo_flung=FlungRedo(5.0))
    assert guard.count == 3


def test_rest_by_drift_ends_the_run_once_the_window_moves_slowly_enough():
    rest = RestDrift(window=4, rest_speed=0.05, after_t=0.095)
    out = run(Scripted(speed=0.01), _start(), 0.01, until=100, observers=[rest])
    assert rest.settled and out.step == 10 and rest.drift == pytest.approx(0.01)  # not before t = 0.095
    rest = RestDrift(window=4, rest_speed=0.05)
    run(Scripted(speed=0.2), _start(), 0.01, until=20, observers=[rest])
    assert not rest.settled and rest.drift == pytest.approx(0.2)


def test_top_speed_with_a_ceiling_raises_the_error_asked_for():
    class Flung(Exception):
        pass

    top = TopSpeed(5.0, error=Flung)
    with pytest.raises(Flung, match="80.0 m/s at t=0.03"):
        run(Scripted(fling={2}), _start(), 0.01, until=5, observers=[top])
    assert top.fastest == 80.0


def test_end_time_step_length_before_step_and_frames():
    moved = []

    def nudge(k, s):
        moved.append(k)
        return ClothState(s.x + 1.0, s.v, s.t)

    frames = FrameRecorder(every=2, last=-1, first=_start())
    solver = Scripted()
    out = run(solver, _start(), lambda k, t: 0.01 if t < 0.03 - 1e-9 else 0.02, until=None, until_time=0.1,
              observers=[frames], before_step=nudge, control=lambda k, t: "late" if t >= 0.03 - 1e-9 else "early")
    assert [c[1] for c in solver.calls] == [0.01, 0.01, 0.01, 0.02, 0.02, 0.02, 0.02]
    assert [c[2] for c in solver.calls] == ["early"] * 3 + ["late"] * 4
    assert out.step == 7 and out.state.t == pytest.approx(0.11) and moved == list(range(7))
    assert float(out.state.x[0, 0]) == pytest.approx(7.0 + 0.1 * 0.11)
    assert frames.times[:3] == [0.0, pytest.approx(0.02), pytest.approx(0.05)]


class _Clock:
    """A wall clock that only the scripted solver moves: `seconds` per step."""

    def __init__(self, seconds: float):
        self.now, self.seconds = 0.0, seconds

    def perf_counter(self) -> float:
        return self.now


def _timed_solver(monkeypatch, seconds_per_step: float) -> Scripted:
    clock = _Clock(seconds_per_step)
    monkeypatch.setattr("tryon.sim.loop.time", clock)
    solver = Scripted()
    step = solver.step

    def timed(state, dt, control=None):
        clock.now += clock.seconds
        return step(state, dt, control)

    solver.step = timed
    return solver


def test_time_limit_is_checked_between_steps(monkeypatch):
    limit = TimeLimit(0.1, explain=lambda rec: f"out of time after {rec.step} steps")
    with pytest.raises(SimulationError, match="out of time after 2 steps"):
        run(_timed_solver(monkeypatch, 0.06), _start(), 0.01, until=50, time_limit=limit)
    # the last step counts too, whether the run ends on a step count or on a simulated time
    with pytest.raises(SimulationError, match="out of time after 2 steps"):
        run(_timed_solver(monkeypatch, 0.06), _start(), 0.01, until=2, time_limit=limit)
    with pytest.raises(SimulationError, match="out of time after 2 steps"):
        run(_timed_solver(monkeypatch, 0.06), _start(), 0.01, until=None, until_time=0.02, time_limit=limit)
    # an observer that ends the run (the cloth at rest) ends it in time
    out = run(_timed_solver(monkeypatch, 0.06), _start(), 0.01, until=50, time_limit=limit,
              observers=[lambda rec: rec.step == 2])
    assert out.step == 2


def test_advance_takes_one_step_from_any_state():
    rec = advance(Scripted(), ClothState(torch.ones(2, 3, dtype=torch.float64), torch.zeros(2, 3, dtype=torch.float64), 1.0), 0.5)
    assert rec.step == 1 and rec.dt == 0.5 and rec.state.t == 1.5
    assert np.allclose(rec.state.x.numpy()[:, 0], 1.05) and rec.before.t == 1.0
