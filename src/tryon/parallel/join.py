"""Joining fine segments into one run, cross-fading across every segment boundary.

Segment j starts at s_j from the coarse predictor's state (plus recovered detail), which
is not exactly where segment j - 1 arrives at s_j: the coarse run drifts from the fine
one, and a viewer would see the cloth jump between two frames ("popping"). Segment j - 1
therefore runs `overlap` steps past s_j, and the joined frames in (s_j, s_j + overlap]
are the blend (1 - w) x_{j-1} + w x_j with w rising smoothly (smoothstep) from 0 to 1
(by the end of segment j if it is shorter than the overlap):
both are simulated states of the same cloth at the same time, and the difference between
them is spread over the overlap instead of shown in one frame. After the overlap the
frames are segment j's own. A blended frame that puts the cloth into an obstacle has
those vertices moved out (`recovery.push_outside`); one whose layers cross each other
or an obstacle is replaced by segment j's own frame (counted in `CrossfadeReport.replaced`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tryon.errors import SimulationError
from tryon.parallel.hierarchy import Hierarchy
from tryon.parallel.recovery import crossings, obstacle_crossings, push_outside, self_intersecting_vertices
from tryon.parallel.segment import SegmentResult


@dataclass
class CrossfadeReport:
    """Per boundary step: how many frames were blended and how many had to be replaced."""

    blended: dict[int, int] = field(default_factory=dict)
    replaced: dict[int, int] = field(default_factory=dict)


def serial_frame_steps(n_steps: int, steps_per_frame: int) -> list[int]:
    """Steps whose states a serial run keeps as frames (after the initial state)."""
    return [k for k in range(1, n_steps + 1) if k % steps_per_frame == 0 or k == n_steps]


def crossfade_weight(step: int, boundary: int, span: int) -> float:
    """w in [0, 1]: the share of the later segment in the joined frame at `step`, rising
    smoothly from 0 at the boundary to 1 at `boundary + span`."""
    if span <= 0 or step >= boundary + span:
        return 1.0
    u = max(0.0, (step - boundary) / span)
    return u * u * (3.0 - 2.0 * u)


def _blend(hier: Hierarchy, earlier: np.ndarray, later: np.ndarray, w: float, t: float) -> tuple[np.ndarray, bool]:
    """(frame, replaced): the blend, made clear of obstacles, or `later` (a simulated
    frame) if the blend crosses itself or an obstacle more than `later` does."""
    x = (1.0 - w) * earlier + w * later
    through_obstacle = obstacle_crossings(hier, x, t)
    if through_obstacle:
        x = push_outside(hier, x, t)
        through_obstacle = obstacle_crossings(hier, x, t)
    blended = len(self_intersecting_vertices(hier, x)) + through_obstacle
    if blended and blended > crossings(hier, later, t):
        return later, True
    return x, False


def join_segments(hier: Hierarchy, segments: list[SegmentResult]) -> tuple[np.ndarray, np.ndarray]:
    """Frames [T, N, 3] and times [T] of the fine run (see `join_with_crossfade`)."""
    positions, times, _ = join_with_crossfade(hier, segments)
    return positions, times


def plain_join(hier: Hierarchy, segments: list[SegmentResult]) -> tuple[list[int], np.ndarray]:
    """Steps [T] (0 first) and frames [T, N, 3]: the initial state, then every segment's own
    frames (up to its end) in order, as with no cross-fade. Raises if a frame is missing
    or duplicated."""
    fine = hier.fine
    steps = [k for seg in segments for k in seg.own_steps]
    expected = serial_frame_steps(fine.num_steps, fine.steps_per_frame)
    if steps != expected:
        missing = sorted(set(expected) - set(steps))[:5]
        extra = sorted(k for k in set(steps) if steps.count(k) > 1 or k not in expected)[:5]
        raise SimulationError(f"time-parallel segments do not join: missing frames at steps {missing}, duplicated or "
                              f"unexpected {extra}")
    frames = [fine.model.initial_state().x.numpy()[None]] + [seg.frames[: len(seg.own_steps)] for seg in segments]
    return [0] + steps, np.concatenate(frames)


def join_with_crossfade(hier: Hierarchy, segments: list[SegmentResult]) -> tuple[np.ndarray, np.ndarray, CrossfadeReport]:
    """`plain_join`, with the frames just after each boundary cross-faded from the previous
    segment's overlap frames (where it ran past its end)."""
    fine = hier.fine
    steps, joined = plain_join(hier, segments)
    index = {k: i for i, k in enumerate(steps)}
    report = CrossfadeReport()
    for prev, seg in zip(segments[:-1], segments[1:]):
        overlap = {k: x for k, x in zip(prev.frame_steps, prev.frames) if k > prev.end}
        span = min(max(overlap, default=seg.start), seg.end) - seg.start  # w reaches 1 within this segment
        for k in seg.own_steps:
            if k in overlap and k < seg.start + span:
                w = crossfade_weight(k, seg.start, span)
                joined[index[k]], replaced = _blend(hier, overlap[k], joined[index[k]], w, k * fine.dt)
                report.blended[seg.start] = report.blended.get(seg.start, 0) + 1
                report.replaced[seg.start] = report.replaced.get(seg.start, 0) + int(replaced)
    return joined, np.asarray(steps) * fine.dt, report
