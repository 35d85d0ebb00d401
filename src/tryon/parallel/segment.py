"""One fine segment of a time-parallel run: detail recovery at its start (unless it is the
first segment, which starts from the scene's exact initial state), then fine steps to its
end, keeping the frames a serial run would keep in that interval, and `overlap` steps
beyond it (frames the join cross-fades with the next segment's first ones).

`segment_run` is a generator so that the same code runs inside a Ray task and in the
in-process executor: it yields a `Progress` after recovery and after every step, and the
driver sends back the segment's end once it is known (adaptive partitions decide it
while the segment already runs)."""

from __future__ import annotations

import os
import signal
import socket
import time
from collections.abc import Generator
from dataclasses import dataclass, field

import numpy as np
import torch

from tryon.errors import SimulationError
from tryon.parallel.hierarchy import Hierarchy
from tryon.parallel.recovery import RecoveryOptions, crossings as start_crossings, recover_details
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.loop import steps
from tryon.sim.model import ClothState

FAULT_ENV = "TRYON_PARALLEL_FAULT"  # chaos testing: "SEGMENT:STEP:MARKER" kills that segment's worker once
CoarsePair = tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass
class SegmentSpec:
    """Segment `index` covers fine steps start..end (end None: decided later) and runs
    `overlap` steps past its end (not past the run's last step) for the join's cross-fade.
    `coarse` holds the coarse (x, v) at the start and one fine step later (None for
    segment 0). `exact`, when given, is the fine (x, v) at the start that the previous
    segment arrived at: the segment starts from it without recovery (a restart, see
    `SegmentResult.start_crossings`)."""

    index: int
    start: int
    end: int | None
    n_steps: int
    steps_per_frame: int
    coarse: CoarsePair | None = None
    recovery: RecoveryOptions = field(default_factory=RecoveryOptions)
    overlap: int = 0
    exact: tuple[np.ndarray, np.ndarray] | None = None
    refused_crossings: int = 0  # with `exact`: the crossings of the recovered start it replaces

    def stop(self, end: int) -> int:
        """The last step this segment simulates when its boundary is `end`."""
        return min(end + self.overlap, self.n_steps)


@dataclass
class Progress:
    index: int
    step: int
    seconds: float  # wall seconds of the last fine step (0 for the start report)
    pid: int
    host: str
    phase: str = "step"  # "start" after recovery (or a restart's exact start), then "step"


@dataclass
class SegmentResult:
    index: int
    start: int
    end: int
    frame_steps: list[int]  # steps of `frames`: the serial run's frame steps in (start, end + overlap]
    frames: np.ndarray  # [F, N, 3]
    x_end: np.ndarray  # the state at `end` (the boundary, before any overlap)
    v_end: np.ndarray
    step_seconds: list[float]
    recovery: dict
    x_start: np.ndarray  # the state the segment started from (after recovery)
    x_upsampled: np.ndarray | None  # u(X_coarse) at the start (None for segment 0)
    pid: int = 0
    host: str = ""
    setup_seconds: float = 0.0
    retried_steps: int = 0
    fail_safe_used: bool = False
    # crossings (cloth through cloth or obstacle) in the recovered start state beyond those
    # of the scene's initial state; such a segment stops at once (no frames) and the driver
    # runs it again from the previous segment's state at the boundary, since no step can
    # undo a crossing; `restarted` is then the refused start's crossings (0: not restarted)
    start_crossings: int = 0
    restarted: int = 0

    @property
    def own_steps(self) -> list[int]:
        """Frame steps up to the segment's end (the rest is its cross-fade overlap)."""
        return [k for k in self.frame_steps if k <= self.end]

    def to_arrays(self) -> dict:
        """Flat arrays for an npz checkpoint (see `from_arrays`)."""
        meta = np.array([self.index, self.start, self.end, self.pid, self.retried_steps, int(self.fail_safe_used)])
        out = {"meta": meta, "frame_steps": np.asarray(self.frame_steps, np.int64), "frames": self.frames,
               "x_end": self.x_end, "v_end": self.v_end, "step_seconds": np.asarray(self.step_seconds),
               "x_start": self.x_start, "setup_seconds": np.array(self.setup_seconds),
               "recovery_changes": np.asarray(self.recovery.get("changes", []), np.float64),
               "recovery_scalars": np.array([self.recovery.get("iterations", 0), self.recovery.get("limit", 0),
                                             float(self.recovery.get("converged", False)), self.recovery.get("seconds", 0.0)])}
        if self.x_upsampled is not None:
            out["x_upsampled"] = self.x_upsampled
        out["restart"] = np.array([self.start_crossings, self.restarted])
        return out

    @classmethod
    def from_arrays(cls, a: dict) -> "SegmentResult":
        index, start, end, pid, retried, fail_safe = (int(v) for v in a["meta"])
        it, limit, conv, sec = a["recovery_scalars"].tolist()
        recovery = {"iterations": int(it), "limit": int(limit), "converged": bool(conv), "seconds": float(sec),
                    "changes": a["recovery_changes"].tolist(), "failed": ""}
        crossings, restarted = (int(v) for v in a["restart"]) if "restart" in a else (0, 0)
        return cls(index, start, end, a["frame_steps"].tolist(), a["frames"], a["x_end"], a["v_end"],
                   a["step_seconds"].tolist(), recovery, a["x_start"], a.get("x_upsampled"), pid, "",
                   float(a["setup_seconds"]), retried, bool(fail_safe), crossings, restarted)


def _injected_fault(index: int, step: int) -> None:
    """With TRYON_PARALLEL_FAULT="SEGMENT:STEP:MARKER" in a worker's environment, the
    worker running SEGMENT kills itself (SIGKILL) on reaching STEP, once: the first to do
    so creates the file MARKER. Set only in Ray workers' environments (the chaos test)."""
    fault = os.environ.get(FAULT_ENV)
    if not fault:
        return
    segment, at, marker = fault.split(":", 2)
    if int(segment) != index or step < int(at):
        return
    try:
        os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return
    os.kill(os.getpid(), signal.SIGKILL)


def segment_run(hier: Hierarchy, spec: SegmentSpec) -> Generator[Progress, int | None, SegmentResult]:
    """Recover (Algorithm 3), then step to the end; yields progress, receives the end."""
    tic = time.perf_counter()
    fine = hier.fine
    solver = ImplicitEulerSolver(fine.model, fine.options)
    pid, host = os.getpid(), socket.gethostname()
    t0 = spec.start * fine.dt
    exact_start = {"iterations": 0, "limit": 0, "converged": True, "seconds": 0.0, "changes": [], "failed": ""}
    crossings = 0
    if spec.exact is not None:
        x0, v0 = spec.exact
        state, x_up, rec = ClothState(torch.from_numpy(x0.copy()), torch.from_numpy(v0.copy()), t0), None, exact_start
    elif spec.coarse is None:
        if spec.start != 0:
            raise SimulationError(f"segment {spec.index} starts at step {spec.start} but has no coarse state")
        state, x_up, rec = fine.model.initial_state(), None, exact_start
    else:
        start_pair, next_pair = spec.coarse
        state, report = recover_details(solver, hier, start_pair, next_pair, t0, fine.dt, spec.recovery)
        x_up = report.start
        rec = {"iterations": report.iterations, "limit": report.limit, "converged": report.converged,
               "seconds": report.seconds, "changes": report.changes, "failed": report.failed,
               "stopped": report.stopped, "detail_kept": report.detail_kept}
        crossings = start_crossings(hier, state.x.numpy(), t0)
        if crossings and crossings <= start_crossings(hier, fine.model.initial_state().x.numpy(), 0.0):
            crossings = 0  # the scene starts with as many: a serial run carries them too
    x_start = state.x.numpy().copy()
    setup = time.perf_counter() - tic
    end = spec.end
    received = yield Progress(spec.index, spec.start, 0.0, pid, host, "start")
    end = received if received is not None else end
    n = fine.model.num_vertices
    if crossings:  # no step can undo a crossing: the driver restarts this segment exactly
        return SegmentResult(spec.index, spec.start, spec.start if end is None else int(end), [], np.zeros((0, n, 3)),
                             x_start, state.v.numpy().copy(), [], rec, x_start, x_up, pid, host, setup,
                             start_crossings=crossings)
    k = spec.start
    frames, frame_steps, seconds = [], [], []
    retried, fail_safe = 0, False
    x_end = v_end = None
    stepper = steps(solver, state, fine.dt, start=k)
    while end is None or k < spec.stop(end):
        record = next(stepper)
        state, stats, k = record.state, record.stats, record.step
        seconds.append(record.seconds)
        retried += int(stats.retried)
        fail_safe |= stats.fallback
        _injected_fault(spec.index, k)
        if k % spec.steps_per_frame == 0 or k == spec.n_steps:
            frames.append(state.x.numpy().copy())
            frame_steps.append(k)
        received = yield Progress(spec.index, k, seconds[-1], pid, host)
        if received is not None:
            end = received
        if end is not None and k > end and x_end is None:
            raise SimulationError(f"segment {spec.index} was told to end at step {end} after it had reached {k}")
        if k == end:
            x_end, v_end = state.x.numpy().copy(), state.v.numpy().copy()
    if x_end is None:  # a segment with no steps of its own
        x_end, v_end = state.x.numpy().copy(), state.v.numpy().copy()
    return SegmentResult(spec.index, spec.start, int(end), frame_steps,
                         np.stack(frames) if frames else np.zeros((0, n, 3)), x_end, v_end, seconds, rec, x_start,
                         x_up, pid, host, setup, retried, fail_safe, restarted=spec.refused_crossings)


def run_segment_to_end(hier: Hierarchy, spec: SegmentSpec) -> SegmentResult:
    """Run a segment whose end is known, start to finish, in this process."""
    if spec.end is None:
        raise SimulationError(f"segment {spec.index} has no end step")
    gen = segment_run(hier, spec)
    next(gen)
    try:
        while True:
            gen.send(None)
    except StopIteration as stop:
        return stop.value
