"""Per-phase profile of the hanging cloth step (docs/ENGINE.md), as one JSON line:

    NUMBA_NUM_THREADS=1 .venv/bin/python scripts/profile_sim_phases.py GRID STEPS
"""

import cProfile
import json
import pstats
import sys
import time

import torch

from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.loop import run
from tryon.sim.scene import example_scene

PHASES = {  # row name: (profiled function, cumulative or own time)
    "proximity (find_proximities)": ("find_proximities", "cumulative"),
    "forces and assembly (assemble, less proximity)": ("assemble", "cumulative"),
    "linear solve (filtered_pcg)": ("filtered_pcg", "cumulative"),
    "CCD and impact zones (resolve_collisions)": ("resolve_collisions", "cumulative"),
    "of which BVH pair queries (overlap_pairs)": ("overlap_pairs", "own"),
}


def main(grid: int, steps: int) -> dict:
    torch.set_num_threads(1)
    scene = example_scene("hanging", grid, dt=0.01)
    solver = ImplicitEulerSolver(scene.model, scene.options)
    state = run(solver, scene.model.initial_state(), scene.dt, until=5).state  # compiled and warm
    profile, iterations = cProfile.Profile(), 0
    tic = time.perf_counter()
    profile.enable()
    for _ in range(steps):
        state, stats = solver.step(state, scene.dt)
        iterations += stats.solver_iterations
    profile.disable()
    wall = (time.perf_counter() - tic) / steps
    table = pstats.Stats(profile).stats  # {(file, line, name): (calls, prim calls, own s, cumulative s, callers)}

    def seconds(name: str, kind: str) -> float:
        return sum(v[3] if kind == "cumulative" else v[2] for k, v in table.items() if k[2] == name) / steps

    ms = {"step": wall * 1000, **{row: 1000 * seconds(*how) for row, how in PHASES.items()}}
    return {"grid": grid, "vertices": scene.model.num_vertices, "pcg_iterations": iterations / steps,
            "ms": {k: round(v, 2) for k, v in ms.items()}}


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]), int(sys.argv[2]))))
