"""The two-level preconditioner: aggregates, the coarse correction against block-Jacobi,
exact solves, thread independence, and the solver that datasets pin."""

import numpy as np
import pytest

from tryon.dataset.generate import DATASET_LINEAR_SOLVER, _task
from tryon.errors import SimulationError
from tryon.sim.integrator import ImplicitEulerSolver, StepOptions
from tryon.sim.linear import (HAVE_CHOLMOD, TWO_LEVEL_MIN_VERTICES, CoarseSpace, aggregate_vertices, auto_solver_pinned, filtered_pcg,
                              resolve_kind, two_level_pcg)
from tryon.sim.loop import run
from tryon.sim.scene import example_scene

pytestmark = pytest.mark.skipif(not HAVE_CHOLMOD, reason="the coarse solve needs CHOLMOD (scikit-sparse)")


def _system(grid: int, steps: int = 10):
    """A hanging cloth's step system after `steps` steps of swinging (pinned corners)."""
    scene = example_scene("hanging", grid, dt=0.01)
    solver = ImplicitEulerSolver(scene.model, StepOptions(linear_solver="pcg"))
    state = run(solver, scene.model.initial_state(), scene.dt, until=steps).state
    obstacles = scene.model.obstacles.vertices_at(0.0)
    system = solver.assemble(state, scene.dt, None, None, obstacles, obstacles)
    return solver.pattern, system.A, system.rhs, ~solver.pinned_mask


def test_aggregates_cover_the_mesh_with_connected_groups_of_neighbours():
    pattern, _, _, _ = _system(20, steps=0)
    agg = aggregate_vertices(pattern.indptr, pattern.indices, 2)
    count = agg.max() + 1
    assert agg.min() == 0 and set(np.unique(agg)) == set(range(count))  # labels 0..count-1, none empty
    sizes = np.bincount(agg)
    assert sizes.min() >= 2 and 6 <= sizes.mean() <= 20  # no lone vertex; a vertex and its 2-ring
    for a in range(count):  # each aggregate is connected in the block graph
        members = set(np.flatnonzero(agg == a))
        seen, todo = set(), [min(members)]
        while todo:
            v = todo.pop()
            if v in seen:
                continue
            seen.add(v)
            todo += [u for u in pattern.indices[pattern.indptr[v]:pattern.indptr[v + 1]] if u in members]
        assert seen == members


def test_two_level_needs_far_fewer_iterations_than_block_jacobi_and_finds_the_same_solution():
    pattern, blocks, rhs, free = _system(40)
    coarse = CoarseSpace(pattern)
    x_jacobi, x_two = np.zeros((pattern.n, 3)), np.zeros((pattern.n, 3))
    it_jacobi = filtered_pcg(pattern.indptr, pattern.indices, blocks, pattern.diag_block, rhs, x_jacobi, free, 1e-10, 5000)
    it_two = two_level_pcg(pattern, coarse, blocks, rhs, x_two, free, 1e-10, 5000)
    assert 0 < it_two < 0.5 * it_jacobi < 2500
    scale = np.abs(x_jacobi).max()
    assert np.abs(x_two - x_jacobi).max() < 1e-6 * scale
    assert np.all(x_two[~free] == 0.0)  # pinned vertices keep their given value


def test_two_level_steps_agree_with_the_exact_solver():
    scene = example_scene("hanging", 12, dt=0.02)
    exact = ImplicitEulerSolver(scene.model, StepOptions(linear_solver="splu"))
    two = ImplicitEulerSolver(scene.model, StepOptions(linear_solver="pcg-two-level", pcg_tol=1e-12))
    assert two.linear.kind == "pcg-two-level" and two.linear.coarse is not None
    s = run(exact, scene.model.initial_state(), 0.02, until=5).state
    a, _ = exact.step(s, 0.02)
    b, _ = two.step(s, 0.02)
    assert np.allclose(a.x.numpy(), b.x.numpy(), atol=1e-9)
    assert two.linear.coarse_failures == 0


def test_an_aggregate_of_pinned_vertices_only_leaves_the_solve_exact():
    pattern, blocks, rhs, free = _system(12, steps=2)
    coarse = CoarseSpace(pattern)
    free = free.copy()
    free[coarse.aggregate == coarse.aggregate[0]] = False  # a whole aggregate pinned
    x = np.zeros((pattern.n, 3))
    it = two_level_pcg(pattern, coarse, blocks, rhs, x, free, 1e-12, 5000)
    assert 0 < it < 5000 and np.all(np.isfinite(x)) and np.all(x[~free] == 0.0)
    ax = np.zeros_like(x)
    from tryon.sim.linear import bsr_matvec

    bsr_matvec(pattern.indptr, pattern.indices, blocks, x, ax)
    assert np.abs((ax - rhs)[free]).max() < 1e-9 * np.abs(rhs[free]).max()


def test_two_level_is_the_same_on_one_thread_and_on_two(on_numba_threads):
    pattern, blocks, rhs, free = _system(24, steps=3)
    coarse = CoarseSpace(pattern)

    def solve(threads):
        x = np.zeros((pattern.n, 3))
        return two_level_pcg(pattern, coarse, blocks, rhs, x, free, 1e-10, 5000, 64), x

    results = on_numba_threads(solve)
    assert 0 < results[0][0] < 5000
    assert results[1][0] == results[0][0] and np.array_equal(results[1][1], results[0][1])


def test_auto_is_two_level_on_large_meshes_unless_pinned():
    assert resolve_kind("auto", TWO_LEVEL_MIN_VERTICES) == "pcg-two-level"
    assert resolve_kind("auto", TWO_LEVEL_MIN_VERTICES - 1) == "pcg"
    assert resolve_kind("splu", 10**6) == "splu"
    with auto_solver_pinned("pcg"):
        assert resolve_kind("auto", 10**6) == "pcg"
        assert resolve_kind("pcg-two-level", 10**6) == "pcg-two-level"  # only 'auto' follows the pin
    assert resolve_kind("auto", 10**6) == "pcg-two-level"
    with pytest.raises(SimulationError, match="cannot pin"):
        with auto_solver_pinned("auto"):
            pass


def _kind_seen(manifest, shared, unit):
    return {"kind": resolve_kind("auto", 10**6)}


def test_dataset_samples_are_made_with_the_pinned_solver():
    assert DATASET_LINEAR_SOLVER == "pcg"  # what the datasets in data/ were made with
    _, sample = _task(_kind_seen, None, None, 0, one_thread=False)
    assert sample["kind"] == DATASET_LINEAR_SOLVER
    assert resolve_kind("auto", 10**6) == "pcg-two-level"
