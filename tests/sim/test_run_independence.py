"""A run's result does not depend on what ran before it in the process: the collision
queries' cached BVH topologies (which decide the order of candidate pairs, and with it the
last bits of every step) belong to each solver."""

import numpy as np

from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.loop import run
from tryon.sim.scene import example_scene


def _run(steps: int) -> np.ndarray:
    scene = example_scene("sphere-drop", 12, dt=0.01)
    solver = ImplicitEulerSolver(scene.model, scene.options)
    return run(solver, scene.model.initial_state(), scene.dt, until=steps).state.x.numpy().copy()


def test_the_same_run_twice_in_one_process_is_the_same_bit_for_bit():
    first = _run(23)  # leaves the trees of its meshes part-way to their next rebuild
    again = _run(23)
    assert np.array_equal(first, again)


def test_two_solvers_stepped_in_turn_each_give_their_run_alone():
    """Two simulations of the same mesh side by side in one process (the time-parallel
    driver builds segment solvers while its coarse run is under way) each own their trees."""
    alone = _run(23)
    scene = example_scene("sphere-drop", 12, dt=0.01)
    solvers = [ImplicitEulerSolver(scene.model, scene.options) for _ in range(2)]
    states = [scene.model.initial_state() for _ in range(2)]
    for _ in range(23):
        for i, solver in enumerate(solvers):
            states[i], _ = solver.step(states[i], scene.dt)
    for state in states:
        assert np.array_equal(state.x.numpy(), alone)
