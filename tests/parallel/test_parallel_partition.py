"""Partition points of time-parallel runs (Liang & Lin 2018, Sec. 5): uniform, the
load-balanced static formula, the online Algorithm 2 and the speedup bounds."""

import math

import numpy as np
import pytest

from tryon.errors import TryonError
from tryon.parallel.partition import (
    AdaptivePartitioner,
    PartitionError,
    balanced_cuts,
    next_balanced_cut,
    speedup_bounds,
    uniform_cuts,
)


def test_uniform_cuts_split_evenly_on_whole_coarse_steps():
    assert uniform_cuts(100, 4) == [0, 25, 50, 75, 100]
    assert uniform_cuts(10, 10) == list(range(11))
    cuts = uniform_cuts(9, 4, multiple=2)
    assert cuts[0] == 0 and cuts[-1] == 9 and len(cuts) == 5
    assert all(c % 2 == 0 for c in cuts[:-1]) and all(b > a for a, b in zip(cuts, cuts[1:]))


def test_balanced_cuts_follow_the_closed_form_and_finish_together():
    N, p, K = 1000, 5, 6.0
    cuts = balanced_cuts(N, p, K)
    q = 1 - 1 / K
    exact = [N * (1 - q**j) / (1 - q**p) for j in range(p + 1)]
    assert np.allclose(cuts, exact, atol=0.5)
    # segment j starts when the coarse run (cost 1 per step) reaches s_j and takes K per step:
    # with the balanced cuts every segment finishes at the same moment
    finish = [exact[j] + K * (exact[j + 1] - exact[j]) for j in range(p)]
    assert np.allclose(finish, finish[0])
    lengths = np.diff(cuts)
    assert np.all(np.diff(lengths) < 0)  # later segments are shorter


def test_balanced_without_a_cheaper_coarse_level_is_uniform():
    assert balanced_cuts(100, 4, 1.0) == uniform_cuts(100, 4)


def test_bad_partitions_raise_tryon_errors():
    with pytest.raises(PartitionError, match="at least 1"):
        uniform_cuts(10, 0)
    with pytest.raises(TryonError, match="fewer workers"):
        uniform_cuts(5, 6)
    with pytest.raises(TryonError, match="coarse"):
        balanced_cuts(10, 6, 4.0, multiple=2)
    with pytest.raises(PartitionError):
        speedup_bounds(0.0, 4)


def test_speedup_bounds_match_the_model():
    K, p = 8.0, 4
    b = speedup_bounds(K, p)
    assert b["uniform"] == pytest.approx(K * p / (K + p - 1))
    assert b["balanced"] == pytest.approx(K - K * (1 - 1 / K) ** p)
    assert b["uniform"] < b["balanced"] < min(K, p)
    assert speedup_bounds(K, 1)["uniform"] == pytest.approx(1.0)
    assert speedup_bounds(K, 1)["balanced"] == pytest.approx(1.0)


def _drive(part: AdaptivePartitioner, coarse_cost: float, fine_cost, multiple: int = 1) -> list[int]:
    position = 0
    while not part.done:
        position += multiple
        part.offer(min(position, part.n_steps), coarse_cost, fine_cost(position))
    return part.cuts


def test_adaptive_cuts_match_balanced_ones_for_a_steady_cost_ratio():
    N, p, K = 400, 4, 5.0
    part = AdaptivePartitioner(N, p)
    cuts = _drive(part, 1.0, lambda pos: K)
    assert len(cuts) == p + 1 and cuts[-1] == N
    assert np.allclose(cuts, balanced_cuts(N, p, K), atol=1.0)
    assert [h["cut"] for h in part.history] == cuts[1:p]
    assert all(h["K"] == pytest.approx(K) for h in part.history)


def test_adaptive_cuts_follow_the_measured_cost_ratio():
    """Before any fine step is measured the prior K applies; once the fine cost is known
    the open cut and all later ones are placed with the measured K."""
    N, p = 600, 4
    prior_only = AdaptivePartitioner(N, p, prior_K=2.0)
    assert np.allclose(_drive(prior_only, 1.0, lambda pos: None), balanced_cuts(N, p, 2.0), atol=1.0)
    part = AdaptivePartitioner(N, p, prior_K=2.0)
    cuts = _drive(part, 1.0, lambda pos: None if pos < 100 else 20.0)
    assert all(h["K"] == pytest.approx(20.0) for h in part.history)
    assert abs(cuts[1] - next_balanced_cut(0, N, p, 20.0)) <= 1
    assert cuts[1] < prior_only.cuts[1] - 100  # the measured K moved the first cut
    expected_rest = np.diff(balanced_cuts(N - cuts[1], p - 1, 20.0))
    assert np.allclose(np.diff(cuts[1:]), expected_rest, atol=1.5)


def test_adaptive_partition_respects_coarse_steps_and_single_segments():
    part = AdaptivePartitioner(100, 3, multiple=4, prior_K=3.0)
    cuts = _drive(part, 0.5, lambda pos: 2.0, multiple=4)
    assert cuts[0] == 0 and cuts[-1] == 100
    assert all(c % 4 == 0 for c in cuts[:-1])
    assert all(b > a for a, b in zip(cuts, cuts[1:]))
    assert AdaptivePartitioner(50, 1).cuts == [0, 50]
    assert AdaptivePartitioner(50, 1).done


@pytest.mark.parametrize("fine_cost", [1.0, 0.5])
def test_adaptive_partition_gives_every_worker_a_segment_when_the_coarse_run_is_not_cheaper(fine_cost):
    """A measured K at or below 1 (a busy machine, a tiny scene) would put the balanced
    cut at the end of the run; every segment still gets at least one coarse step."""
    for N, p, m in [(30, 2, 1), (30, 2, 3), (100, 4, 4)]:
        cuts = _drive(AdaptivePartitioner(N, p, multiple=m), 1.0, lambda pos: fine_cost, multiple=m)
        assert len(cuts) == p + 1 and cuts[0] == 0 and cuts[-1] == N
        assert all(b > a for a, b in zip(cuts, cuts[1:]))


def test_next_balanced_cut_is_uniform_for_k_one_and_ends_the_last_segment():
    assert next_balanced_cut(10, 110, 4, 1.0) == pytest.approx(35.0)
    assert next_balanced_cut(10, 110, 1, 7.0) == 110
    q = 1 - 1 / 7.0
    assert next_balanced_cut(0, 100, 3, 7.0) == pytest.approx(100 * (1 - q) / (1 - q**3))
    assert math.isclose(sum(np.diff(balanced_cuts(100, 3, 7.0))), 100)


def test_scheduler_simulation_reproduces_the_model_bounds_for_steady_costs(tmp_path):
    from tryon.bench.parallel import plot_scheduler, scheduler_predictions, simulate_schedule

    n, K = 20000, 6.0
    fine, coarse = np.full(n, K), np.ones(n)
    for p in (2, 8, 64):
        bounds = speedup_bounds(K, p)
        for partition in ("uniform", "balanced"):
            predicted = fine.sum() / simulate_schedule(fine, coarse, 0.0, p, partition)
            assert predicted == pytest.approx(bounds[partition], rel=0.01)
    # recovery time at every segment start costs speedup
    slow = fine.sum() / simulate_schedule(fine, coarse, 5000.0, 8, "balanced")
    assert slow < 0.9 * speedup_bounds(K, 8)["balanced"]
    # the cross-fade overlap: balanced segments end together, all but the last 100 steps later
    balanced = simulate_schedule(fine, coarse, 0.0, 8, "balanced")
    assert simulate_schedule(fine, coarse, 0.0, 8, "balanced", overlap=100) == pytest.approx(balanced + 100 * K, rel=1e-3)
    rows = scheduler_predictions(np.array([2.0, 4.0]), np.array([0.5, 0.5]), 0.0, "toy")
    assert {r["workers"] for r in rows} == {8, 16, 32, 64, 128, 256, 512}
    assert all(0 < r["efficiency"] <= 1 for r in rows)
    plot_scheduler(rows, tmp_path / "s.png")
    assert (tmp_path / "s.png").stat().st_size > 10000
