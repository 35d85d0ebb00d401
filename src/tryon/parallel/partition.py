"""Where to cut the time axis (Liang & Lin, SCA 2018, Sec. 5).

A run of N fine steps is split at partition points 0 = s_0 < s_1 < ... < s_p = N; fine
segment j simulates steps s_j .. s_{j+1} and may start once the coarse run has reached
s_j. With a fine step K times as expensive as a coarse one (per simulated second):

* uniform:  s_j = N j / p; the last segment starts at (p-1)/p of the coarse run, so the
  speedup over the serial fine run is bounded by  K p / (K + p - 1);
* balanced (static): every segment ends at the same moment, s_j + K (s_{j+1} - s_j) =
  K s_1, which gives s_j = N (1 - q^j) / (1 - q^p), q = 1 - 1/K, and the bound
  K (1 - (1 - 1/K)^p);
* adaptive (the paper's Algorithm 2): K is not known in advance; it is estimated online
  from the measured seconds per step of the running coarse simulation and of the fine
  segments, and the next cut is placed, segment by segment, by the balanced rule applied
  to what remains: s_{j+1} = s_j + (N - s_j) (1 - q) / (1 - q^(p - j)).

Cuts other than 0 and N lie on whole coarse steps (multiples of the coarse/fine dt ratio).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from tryon.errors import TryonError

PARTITIONS = ("uniform", "balanced", "adaptive")


class PartitionError(TryonError):
    """A partition request is impossible (no steps, no workers, bad K)."""


def _check(n_steps: int, parts: int, multiple: int = 1) -> None:
    if n_steps < 1:
        raise PartitionError(f"a run needs at least one step to partition, got {n_steps}")
    if parts < 1:
        raise PartitionError(f"the number of segments must be at least 1, got {parts}")
    if parts > max(1, n_steps // multiple):
        raise PartitionError(f"{parts} segments need at least {parts} coarse steps, but the run has {n_steps} fine "
                             f"steps ({n_steps // multiple} coarse); use fewer workers or a longer run")


def _snap(cuts: list[float], n_steps: int, multiple: int) -> list[int]:
    """Round interior cuts to multiples of `multiple` keeping every segment at least one
    coarse step long (0 and N stay); `_check` guarantees there is room."""
    p = len(cuts) - 1
    out = [0] + [int(round(c / multiple)) * multiple for c in cuts[1:-1]] + [n_steps]
    for j in range(1, p):  # forwards: at least one coarse step after the previous cut
        out[j] = max(out[j], out[j - 1] + multiple)
    for j in range(p - 1, 0, -1):  # backwards: room for the segments after it
        room = ((out[j + 1] - 1) // multiple) * multiple  # the largest whole coarse step before the next cut
        out[j] = min(out[j], room)
    if any(b <= a for a, b in zip(out, out[1:])):
        raise PartitionError(f"cannot place {p} segments of whole coarse steps ({multiple} fine steps) in {n_steps} steps")
    return out


def uniform_cuts(n_steps: int, parts: int, multiple: int = 1) -> list[int]:
    """s_j = N j / p (rounded to whole coarse steps)."""
    _check(n_steps, parts, multiple)
    return _snap([n_steps * j / parts for j in range(parts + 1)], n_steps, multiple)


def balanced_cuts(n_steps: int, parts: int, K: float, multiple: int = 1) -> list[int]:
    """Load-balanced static cuts s_j = N (1 - q^j) / (1 - q^p), q = 1 - 1/K."""
    _check(n_steps, parts, multiple)
    if not K > 1.0 or not math.isfinite(K):
        return uniform_cuts(n_steps, parts, multiple)  # K <= 1: the coarse run is no cheaper
    q = 1.0 - 1.0 / K
    return _snap([n_steps * (1 - q**j) / (1 - q**parts) for j in range(parts + 1)], n_steps, multiple)


def next_balanced_cut(start: int, n_steps: int, parts_left: int, K: float) -> float:
    """The balanced rule on the remaining interval: the end of a segment starting at
    `start` when `parts_left` segments (this one included) share the steps start..N."""
    if parts_left <= 1:
        return float(n_steps)
    if not K > 1.0 or not math.isfinite(K):
        return start + (n_steps - start) / parts_left
    q = 1.0 - 1.0 / K
    return start + (n_steps - start) * (1 - q) / (1 - q**parts_left)


def speedup_bounds(K: float, p: int) -> dict:
    """Model speedups over the serial fine run: uniform K p / (K + p - 1), balanced
    K (1 - (1 - 1/K)^p) (both ignore recovery and communication)."""
    if K <= 0 or p < 1:
        raise PartitionError(f"speedup bounds need K > 0 and p >= 1, got K={K}, p={p}")
    balanced = K * (1 - (1 - 1 / K) ** p) if K > 1 else float(min(p, 1))
    return {"uniform": K * p / (K + p - 1), "balanced": balanced}


@dataclass
class AdaptivePartitioner:
    """Online cuts (Algorithm 2). Feed it the measured costs as the run goes; after every
    coarse step, `offer` the coarse run's position and it says whether the open segment
    ends there (and the next one starts).

    `coarse_s_per_step` is per fine step of simulated time (coarse seconds per coarse step
    divided by the dt ratio); `fine_s_per_step` comes from the running fine segments. Until
    a fine step has been measured, `prior_K` stands in for K. `cuts` grows from [0]; segment
    j ends at cuts[j + 1] once that is known, and the last segment ends at N."""

    n_steps: int
    parts: int
    multiple: int = 1
    prior_K: float = 4.0
    cuts: list[int] = field(default_factory=lambda: [0])
    history: list[dict] = field(default_factory=list)

    def __post_init__(self) -> None:
        _check(self.n_steps, self.parts, self.multiple)
        if self.parts == 1 and len(self.cuts) == 1:
            self.cuts.append(self.n_steps)

    @property
    def done(self) -> bool:
        return self.cuts[-1] >= self.n_steps

    def end_of(self, segment: int) -> int | None:
        return self.cuts[segment + 1] if segment + 1 < len(self.cuts) else None

    def estimate_K(self, coarse_s_per_step: float | None, fine_s_per_step: float | None) -> float:
        if not coarse_s_per_step or not fine_s_per_step:
            return self.prior_K
        return max(fine_s_per_step / coarse_s_per_step, 1.0 + 1e-6)

    def target(self, K: float) -> float:
        """Where the open segment should end under the current K estimate, leaving at
        least one coarse step for each segment after it (a K near 1, measured on a busy
        machine, would otherwise give the whole run to the open segment and leave
        workers idle)."""
        parts_left = self.parts - (len(self.cuts) - 1)
        latest = self.n_steps - (parts_left - 1) * self.multiple
        return min(next_balanced_cut(self.cuts[-1], self.n_steps, parts_left, K), float(latest))

    def offer(self, position: int, coarse_s_per_step: float | None, fine_s_per_step: float | None) -> int | None:
        """The coarse run stands at fine step `position` (a whole coarse step). Returns the
        new cut when the open segment should end here, else None."""
        if self.done or position <= self.cuts[-1]:
            return None
        K = self.estimate_K(coarse_s_per_step, fine_s_per_step)
        if position >= self.n_steps:
            return self._cut(self.n_steps, K)
        if position >= self.target(K) - 0.5 * self.multiple:
            return self._cut(position, K)
        return None

    def _cut(self, position: int, K: float) -> int:
        self.cuts.append(int(position))
        self.history.append({"cut": int(position), "K": float(K)})
        if position < self.n_steps and len(self.cuts) == self.parts:
            self.cuts.append(self.n_steps)  # the segment just started is the last one
        return int(position)
