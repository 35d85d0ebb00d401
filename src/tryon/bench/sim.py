"""`tryon bench sim`: seconds per step of the built-in `hanging` and `sphere-drop` scenes
at several grid sizes and thread counts, with a forces / solve / collision breakdown and
ratios against ARCSim 0.3.1 measured on this kind of machine (anchors shipped in
tryon/bench/anchors, from the project's shared reference measurements).

Each configuration runs in its own process so that thread counts (torch, numba, BLAS) are
set before any library starts its thread pool.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from importlib import resources
from pathlib import Path

from tryon.io.atomic import atomic_write
from tryon.io.json_safe import dumps_json

SCENE_ANCHOR = {"hanging": "hang", "sphere-drop": "sphere"}


def arcsim_anchor(scene: str, grid: int, threads: int) -> float | None:
    """ARCSim seconds per step (dt = 0.01) for a scene/grid/threads, or None."""
    key = f"bench/{SCENE_ANCHOR.get(scene, scene)}{grid}.json"
    text = resources.files("tryon.bench").joinpath("anchors/arcsim_cpu_round2.jsonl").read_text()
    for line in text.splitlines():
        rec = json.loads(line)
        if rec["conf"] == key and rec["threads"] == threads:
            return float(rec["wall_per_step_mean_sel"])
    return None


def newton_anchor(grid: int) -> float | None:
    """Newton Style3D CPU seconds per 0.01 s frame on the hanging cloth, from the anchors."""
    text = resources.files("tryon.bench").joinpath("anchors/newton_cpu_matrix.jsonl").read_text()
    for line in text.splitlines():
        rec = json.loads(line)
        if rec.get("solver") == "style3d" and rec.get("scene") == "hang" and rec.get("res") == grid:
            return float(rec["s_per_frame_median"])
    return None


def measure_one(scene_name: str, grid: int, steps: int, warmup: int = 2) -> dict:
    """Time `steps` steps of an example scene in this process (threads already set)."""
    import numpy as np

    from tryon.sim.integrator import ImplicitEulerSolver, StepStats
    from tryon.sim.loop import run
    from tryon.sim.loop import steps as sim_steps
    from tryon.sim.metrics import state_metrics
    from tryon.sim.scene import example_scene

    scene = example_scene(scene_name, grid, dt=0.01)
    solver = ImplicitEulerSolver(scene.model, scene.options)
    # JIT compilation and CHOLMOD analysis, not timed (as ARCSim's init_s)
    state = run(solver, scene.model.initial_state(), scene.dt, until=warmup).state
    totals = StepStats()
    per_step = []
    for rec in sim_steps(solver, state, scene.dt, start=warmup, stop=warmup + steps):
        per_step.append(rec.seconds)
        totals.merge(rec.stats)
        state = rec.state
    met = state_metrics(scene.model, state.x.numpy(), state.t)
    n = max(steps, 1)
    return {
        "scene": scene_name,
        "grid": f"{grid}x{grid}",
        "vertices": scene.model.num_vertices,
        "dt": scene.dt,
        "steps": steps,
        "s_per_step": float(np.mean(per_step)),
        "s_per_step_median": float(np.median(per_step)),
        "breakdown_s_per_step": {k: v / n for k, v in totals.seconds.items()},
        "linear_solver": solver.linear.kind,
        "substeps": totals.substeps,
        "contacts_per_step": totals.contacts / n,
        "max_strain": met["max_strain"],
        "intersections": met["self_intersections"] + met["obstacle_intersections"],
        "min_obstacle_distance": met["min_obstacle_distance"],
    }


def _run_child(scene: str, grid: int, steps: int, threads: int) -> dict:
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        env[var] = str(threads)
    code = (
        "import json, sys, torch; torch.set_num_threads(%d); "
        "from tryon.bench.sim import measure_one; "
        "print('RESULT ' + json.dumps(measure_one(%r, %d, %d)))" % (threads, scene, grid, steps)
    )
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            rec = json.loads(line[7:])
            rec["threads"] = threads
            return rec
    return {"scene": scene, "grid": f"{grid}x{grid}", "threads": threads, "error": proc.stderr.strip().splitlines()[-1:] or ["no output"]}


def run_sim_bench(out_json: str | Path, quick: bool = False, threads: list[int] | None = None, grids: list[int] | None = None) -> list[dict]:
    threads = threads or [1, 2]
    grids = grids or [16, 32, 64, 128]
    configs = [("hanging", g) for g in grids] + [("sphere-drop", g) for g in grids if g <= 64]
    records = []
    for scene, grid in configs:
        for th in threads:
            steps = 5 if quick else (40 if grid >= 128 else 100)
            rec = _run_child(scene, grid, steps, th)
            ref = arcsim_anchor(scene, grid, th)
            if ref is not None and "s_per_step" in rec:
                rec["arcsim_s_per_step"] = ref
                rec["speedup_vs_arcsim"] = ref / rec["s_per_step"]
            if scene == "hanging" and "s_per_step" in rec:
                newton = newton_anchor(grid)
                if newton is not None:
                    rec["newton_style3d_s_per_0.01s"] = newton
                    rec["speedup_vs_newton_style3d"] = newton / rec["s_per_step"]
            records.append(rec)
            _print_row(rec)
    _compare_with_newton(records, grids, quick)
    with atomic_write(out_json) as fh:
        fh.write(dumps_json(records, indent=2))
    print(f"wrote {out_json}")
    return records


def _compare_with_newton(records: list[dict], grids: list[int], quick: bool) -> None:
    """With the optional `newton` package installed, time Newton's Style3D cloth solver on the
    same hanging cloth in this process and add the ratio to our 1-thread records."""
    from tryon.bench.newton_ref import newton_available, run_newton_hanging

    if not newton_available():
        print("newton not installed: ratios use the Newton anchors (pip install 'tryon[newton]' to measure it here)")
        return
    for grid in grids:
        ref = run_newton_hanging(grid, frames=3 if quick else 25)
        for rec in records:
            if rec["scene"] == "hanging" and rec["grid"] == f"{grid}x{grid}" and "s_per_step" in rec:
                rec["newton_measured"] = ref
                rec["speedup_vs_newton_measured"] = ref["s_per_frame_median"] / rec["s_per_step"]
        print(f"newton style3d {grid}x{grid}: {ref['s_per_frame_median'] * 1000:.1f} ms per 0.01 s frame (measured here)")


def _print_row(r: dict) -> None:
    if "error" in r:
        print(f"{r['scene']:12s} {r['grid']:>8s} thr={r['threads']} ERROR {r['error']}")
        return
    b = r["breakdown_s_per_step"]
    ratio = f"{r['speedup_vs_arcsim']:6.1f}x ARCSim" if "speedup_vs_arcsim" in r else ""
    print(
        f"{r['scene']:12s} {r['grid']:>8s} thr={r['threads']} {r['s_per_step'] * 1000:8.1f} ms/step "
        f"(forces {b['forces'] * 1000:.1f}, solve {b['solve'] * 1000:.1f}, collision {b['collision'] * 1000:.1f}) "
        f"{ratio}  strain {r['max_strain'] * 100:.1f}%  isect {r['intersections']}",
        flush=True,
    )
