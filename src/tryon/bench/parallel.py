"""`tryon bench parallel`: time-parallel against serial runs of a garment animation and of
`sphere-drop`, the model bounds, popping errors at segment boundaries, a scheduler
simulation for many workers, and pictures.

For each scene: the serial fine run (timed, every step's state kept), then time-parallel
runs on a local Ray for every worker count P (Ray start-up and worker warm-up are
excluded from the timing and reported apart). Records carry the measured K (fine over
coarse seconds per step), the speedup over the serial run against the bounds
K p / (K + p - 1) and K - K (1 - 1/K)^p, and the relative curvature error at every
segment start before (upsampled coarse state) and after detail recovery, and the same
for recovery alone started from the serial run's exact coarse-scale states (what the
paper's 46 % -> 14 % isolates: the coarse predictor's own shape error is not recovery's),
and the same error of the serial run's twin, started from positions moved by 1 um of
noise (`serial_run(perturb=...)`): the cloth's own sensitivity, under which no start state
can be judged closer to the serial run.

The scheduler simulation replays the measured per-step costs (fine, coarse, and a segment's
start-up: upsampling, crossing checks, recovery, solver set-up),
tiled to a long run, through the partition model to predict speedup and efficiency for
P = 8 ... 512 (`<json>-scheduler.png`). The pop a viewer sees is measured on the joined
frames against the serial run's, with and without the cross-fade (`popping`), and
`<json>-boundary.png` shows the garment around the first segment boundary: serial,
cross-faded and plain joins.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from tryon.io.atomic import atomic_write
from tryon.parallel.coarse import CoarseRun
from tryon.parallel.curvature import relative_curvature_error
from tryon.parallel.driver import ParallelOptions, simulate_time_parallel
from tryon.parallel.executors import worker_threads
from tryon.parallel.hierarchy import Hierarchy, build_hierarchy
from tryon.parallel.join import plain_join
from tryon.parallel.recovery import RecoveryOptions, oracle_recovery_errors
from tryon.parallel.partition import balanced_cuts, speedup_bounds, uniform_cuts
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.loop import steps
from tryon.sim.model import ClothState
from tryon.sim.scene import Scene, example_scene
from tryon.io.json_safe import dumps_json

SCHEDULER_P = (8, 16, 32, 64, 128, 256, 512)
PROJECTED_P = 128  # the worker count the K probes project the speedup to
DRAPE = {"height_cm": 172.0, "weight_kg": 70.0, "gender": "female", "garment": "tshirt", "size": "M",
         "fabric": "gray-interlock"}
# The default workloads: the T-shirt at 1 cm edges through two cyclic motions played for
# about 8 s each, and sphere-drop at 64 x 64; --quick: a 3 cm T-shirt walking 0.4 s and a
# 17 x 17 sphere-drop.
GARMENT_EDGE, QUICK_EDGE = 0.01, 0.03
GARMENT_MOTIONS = {"walk": 4, "arm-raise": 3}  # motion: repetitions (walk 2.2 s, arm-raise 2.8 s)
SPHERE_RESOLUTION, QUICK_SPHERE_RESOLUTION = 64, 17
PROBE_EDGES = (0.01, 0.005)  # garment edge lengths whose K is probed and projected to PROJECTED_P
PROBE_STEPS = 30  # fine steps of a K probe: the 0.2 s blend from the drape's pose and 0.1 s of the motion


def bench_drape_dir(edge_length: float = GARMENT_EDGE) -> Path:
    """The bench's T-shirt drape at `edge_length`, made once and cached."""
    from tryon.drape.dress import cache_dir

    out = cache_dir() / f"bench-parallel-drape-{edge_length * 1000:g}mm"
    if not (out / "drape_state.npz").exists():
        from tryon.body.fit import Measurements
        from tryon.drape import DrapeRequest, drape
        from tryon.drape.outputs import write_outputs

        d = DRAPE
        req = DrapeRequest(Measurements(height_cm=d["height_cm"], gender=d["gender"], weight_kg=d["weight_kg"]),
                           garment=d["garment"], size=d["size"], fabric=d["fabric"], edge_length=edge_length)
        write_outputs(drape(req, progress=False), out)
    return out


def bench_scenes(quick: bool, only: list[str] | None = None) -> list[Scene]:
    """The workloads (named as their records' `scene`), or those of them named in `only`."""
    from tryon.drape.animate import animation_scene

    known = [f"animate-{m}" for m in (["walk"] if quick else GARMENT_MOTIONS)] + ["sphere-drop"]
    wanted = known if not only else list(only)
    unknown = sorted(set(wanted) - set(known))
    if unknown:
        from tryon.errors import TryonError

        raise TryonError(f"unknown parallel bench scene(s) {', '.join(unknown)}; choose from {', '.join(known)}")
    scenes = []
    for name in wanted:
        if name == "sphere-drop":
            res = QUICK_SPHERE_RESOLUTION if quick else SPHERE_RESOLUTION
            scenes.append(example_scene("sphere-drop", res, duration=0.4 if quick else 1.0))
            continue
        motion = name.removeprefix("animate-")
        # a short blend from the drape's pose, so that most of the run is the motion
        scenes.append(animation_scene(bench_drape_dir(QUICK_EDGE if quick else GARMENT_EDGE), motion, dt=0.01,
                                      duration=0.4 if quick else None, blend_time=0.2,
                                      repeat=1 if quick else GARMENT_MOTIONS[motion]))
    return scenes


def probe_costs(scene: Scene, hier: Hierarchy, fine_steps: int = PROBE_STEPS) -> tuple[float, float]:
    """Median seconds of a fine step and of the coarse run per fine step, from a short run
    of each level from the start (three steps first to warm up the solvers)."""
    solver = ImplicitEulerSolver(scene.model, scene.options)
    seconds = [rec.seconds for rec in steps(solver, scene.model.initial_state(), scene.dt, stop=fine_steps + 3)][3:]
    run = CoarseRun(hier)
    while run.position < (fine_steps + 3) * hier.dt_ratio and run.position < scene.num_steps:
        run.advance()
    coarse = np.asarray(run.seconds[3:] or run.seconds) / hier.dt_ratio
    return float(np.median(seconds)), float(np.median(coarse))


def k_probes(motion: str = "walk", edges: tuple[float, ...] = PROBE_EDGES, recovery_s: float | None = None) -> list[dict]:
    """K of the garment workload at each edge length, measured on a short run of both
    levels, and the speedup the scheduler simulation predicts at `PROJECTED_P` workers
    from those costs (and a segment start-up of `recovery_s`, default: 20 fine steps)."""
    from tryon.drape.animate import animation_scene

    out = []
    for edge in edges:
        scene = animation_scene(bench_drape_dir(edge), motion, dt=0.01, blend_time=0.2, repeat=GARMENT_MOTIONS[motion])
        hier = build_hierarchy(scene)
        with worker_threads():
            fine, coarse = probe_costs(scene, hier)
        start_up = 20 * fine if recovery_s is None else recovery_s
        overlap = int(round(ParallelOptions().crossfade / scene.dt))
        projected = scheduler_predictions(np.full(64, fine), np.full(64, coarse), start_up, scene.name, overlap,
                                          workers=(PROJECTED_P,))
        best = max(projected, key=lambda r: r["predicted_speedup"])
        out.append({"scene": scene.name, "edge_length": edge, "fine_vertices": hier.fine.model.num_vertices,
                    "coarse_vertices": hier.coarse.model.num_vertices, "dt_ratio": hier.dt_ratio,
                    "fine_s_per_step": fine, "coarse_s_per_fine_step": coarse, "K": fine / coarse,
                    "projected_workers": PROJECTED_P, "projected_partition": best["partition"],
                    "projected_speedup": best["predicted_speedup"],
                    "projected_share_of_K": best["predicted_speedup"] / (fine / coarse)})
    return out


SPREAD_PERTURBATION = 1e-6  # m: the start perturbation of the serial run's twin (`serial_run(perturb=...)`)


def serial_run(scene: Scene, perturb: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The serial fine run: states [N+1, n, 3] at every step and seconds per step [N]. With
    `perturb`, its twin: the same run from start positions moved by Gaussian noise of that
    standard deviation (m, fixed seed), which measures how far two equally valid serial
    runs drift apart (the floor under any start-state error at a boundary)."""
    solver = ImplicitEulerSolver(scene.model, scene.options)
    state = scene.model.initial_state()
    if perturb:
        noise = np.random.default_rng(0).normal(0.0, perturb, tuple(state.x.shape))
        noise[scene.model.pinned.numpy()] = 0.0
        state = ClothState(state.x + torch.from_numpy(noise), state.v, state.t)
    xs, seconds = [state.x.numpy().copy()], []
    for rec in tqdm(steps(solver, state, scene.dt, stop=scene.num_steps), total=scene.num_steps,
                    desc=f"serial {scene.name}" + (" (perturbed twin)" if perturb else ""), leave=False, disable=None):
        seconds.append(rec.seconds)
        xs.append(rec.state.x.numpy().copy())
    return np.stack(xs), np.asarray(seconds)


def coarse_costs(hier: Hierarchy) -> np.ndarray:
    """Seconds per fine step of the coarse run over the whole scene."""
    run = CoarseRun(hier)
    while run.position < hier.fine.num_steps:
        run.advance()
    return np.repeat(np.asarray(run.seconds) / hier.dt_ratio, hier.dt_ratio)[: hier.fine.num_steps]


_ORACLE: dict = {}  # (scene, hierarchy fingerprint, step) -> recovery from the serial run's exact coarse states
LONG_RECOVERY = RecoveryOptions(tolerance=1e-5, max_iterations=10)  # recovery run to 10 iterations


def boundary_errors(hier: Hierarchy, segments, states: np.ndarray, twin: np.ndarray | None = None) -> list[dict]:
    """At every segment start: the relative curvature error against the serial state of the
    run's own start states (coarse predictor + recovery) and of recovery alone from the
    serial run's exact coarse-scale states (`oracle_recovery_errors`, cached per step);
    the same error and the mean distance (mm) of the serial run's perturbed `twin` there
    (`serial_spread`, `serial_spread_mm`: what two equally valid serial runs differ by);
    and the pop a viewer sees, the mean jump (mm) from the previous segment's end to this
    segment's start at the same time, next to the serial run's mean motion in one step."""
    model = hier.fine.model
    solver = ImplicitEulerSolver(model, hier.fine.options)
    identity = (hier.fine.name, hier.fingerprint())
    out = []
    for prev, s in zip([None, *segments[:-1]], segments):
        if s.x_upsampled is None:
            continue
        ref = states[s.start]
        out.append({"step": s.start, "before": relative_curvature_error(model, s.x_upsampled, ref),
                    "after": relative_curvature_error(model, s.x_start, ref),
                    "recovery_iterations": s.recovery["iterations"], "recovery_s": s.recovery["seconds"],
                    "setup_s": s.setup_seconds,
                    "detail_kept": s.recovery.get("detail_kept", 1.0),
                    "serial_step_mm": 1000 * float(np.linalg.norm(states[s.start + 1] - ref, axis=1).mean())})
        if twin is not None:
            out[-1].update(serial_spread=relative_curvature_error(model, twin[s.start], ref),
                           serial_spread_mm=1000 * float(np.linalg.norm(twin[s.start] - ref, axis=1).mean()))
        if prev is not None and prev.end == s.start:
            jump = np.linalg.norm(s.x_start - prev.x_end, axis=1)
            out[-1].update(jump_mm=1000 * float(jump.mean()), jump_max_mm=1000 * float(jump.max()),
                           pop_curvature=relative_curvature_error(model, s.x_start, prev.x_end))
        key = (*identity, s.start)
        if key not in _ORACLE and s.start + 1 < len(states):
            _ORACLE[key] = (oracle_recovery_errors(solver, hier, states, s.start),
                            oracle_recovery_errors(solver, hier, states, s.start, LONG_RECOVERY))
        if key in _ORACLE:
            default, long = _ORACLE[key]
            out[-1].update(exact_coarse_before=default["before"], exact_coarse_after=default["after"],
                           exact_coarse_after_10=long["after"])
    return out


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _frame_excess(positions: np.ndarray, serial: np.ndarray) -> np.ndarray:
    """Per frame transition: mean over vertices of |(x_{f+1} - x_f) - (s_{f+1} - s_f)| (m),
    how much more (or otherwise) the cloth moves between two frames than in the serial run."""
    return np.linalg.norm(np.diff(positions, axis=0) - np.diff(serial, axis=0), axis=2).mean(axis=1)


def popping(result, states: np.ndarray) -> dict:
    """The pop a viewer sees, from the joined frames against the serial run's frames: the
    largest frame-to-frame excess motion (`_frame_excess`) near each boundary (from one
    frame before it to one frame after its cross-fade), averaged over boundaries, with and
    without the cross-fade (the latter joins the segments' own frames, as with
    --crossfade 0), next to the median excess away from boundaries and the serial run's
    mean motion per frame (segment 0, exactly the serial run, left out of the median)."""
    segs = result.segments
    steps, plain = plain_join(result.hierarchy, segs)
    serial = states[steps]
    span = result.summary["parallel"]["crossfade"]["steps"]
    near = np.zeros(len(steps) - 1, bool)
    windows = []
    for s in segs[1:]:
        lo = max(0, int(np.searchsorted(steps, s.start)) - 1)
        hi = int(np.searchsorted(steps, min(s.start + span, s.end))) + 1
        near[lo:hi] = True
        windows.append((lo, hi))
    faded, raw = _frame_excess(result.positions, serial), _frame_excess(plain, serial)
    away = ~near & (np.asarray(steps[1:]) > segs[1].start if len(segs) > 1 else np.zeros(len(near), bool))
    motion = np.linalg.norm(np.diff(serial, axis=0), axis=2).mean(axis=1)
    return {"pop_crossfade_mm": _mean([1000 * faded[a:b].max() for a, b in windows]),
            "pop_plain_mm": _mean([1000 * raw[a:b].max() for a, b in windows]),
            "pop_baseline_mm": 1000 * float(np.median(faded[away])) if away.any() else None,
            "serial_frame_mm": 1000 * float(motion.mean())}


def parallel_record(scene: Scene, hier: Hierarchy, states: np.ndarray, serial_s: float, workers: int,
                    partition: str, twin: np.ndarray | None = None) -> tuple[dict, object]:
    opts = ParallelOptions(workers=workers, partition=partition)
    r = simulate_time_parallel(scene, opts, progress=False, hierarchy=hier)
    par = r.summary["parallel"]
    K = par["K"]
    errors = boundary_errors(hier, r.segments, states, twin)
    record = {
        "scene": scene.name, "workers": workers, "partition": partition, "segments": len(r.segments),
        "cuts": par["cuts"], "fine_vertices": hier.fine.model.num_vertices,
        "coarse_vertices": hier.coarse.model.num_vertices, "steps": scene.num_steps,
        "serial_s": serial_s, "parallel_s": r.summary["wall_s"], "ray_startup_s": par["ray_startup_s"],
        "speedup": serial_s / r.summary["wall_s"], "K": K,
        "bound_uniform": speedup_bounds(K, workers)["uniform"] if K else None,
        "bound_balanced": speedup_bounds(K, workers)["balanced"] if K else None,
        "curvature_error_before": _mean([e["before"] for e in errors]),
        "curvature_error_after": _mean([e["after"] for e in errors]),
        "curvature_error_exact_coarse_before": _mean([e["exact_coarse_before"] for e in errors if "exact_coarse_before" in e]),
        "curvature_error_exact_coarse_after": _mean([e["exact_coarse_after"] for e in errors if "exact_coarse_after" in e]),
        "curvature_error_exact_coarse_after_10_iterations": _mean([e["exact_coarse_after_10"] for e in errors
                                                                   if "exact_coarse_after_10" in e]),
        "curvature_error_serial_spread": _mean([e["serial_spread"] for e in errors if "serial_spread" in e]),
        "serial_spread_mm": _mean([e["serial_spread_mm"] for e in errors if "serial_spread_mm" in e]),
        "boundary_jump_mm": _mean([e["jump_mm"] for e in errors if "jump_mm" in e]),
        "serial_step_mm": _mean([e["serial_step_mm"] for e in errors]),
        **popping(r, states), "crossfade_s": opts.crossfade,
        "crossfade_replaced_frames": sum(par["crossfade"]["replaced_frames"].values()),
        "detail_carried": hier.detail is not None,
        "obstacle_proxies": hier.obstacle_proxies,
        "boundaries": errors, "resubmitted": par["resubmitted"],
        # segments whose recovered start crossed itself, run again from the previous one's
        # end: their boundaries are exact and left out of the curvature and jump means
        "restarted_segments": len(par["restarted_segments"]), "intersections": r.summary["intersections"],
        "max_deviation_from_serial_m": float(np.abs(r.positions[-1] - states[-1]).max()),
    }
    return record, r


def simulate_schedule(fine: np.ndarray, coarse: np.ndarray, recovery_s: float, p: int, partition: str,
                      overlap: int = 0) -> float:
    """Wall time of a time-parallel run with p segments given per-step costs: segment j
    starts once the coarse run has passed s_j + 1 (plus its recovery) and runs its steps,
    plus the cross-fade overlap (at most the next segment's length) unless it is the last."""
    n = len(fine)
    K = float(fine.mean() / coarse.mean())
    cuts = np.asarray(balanced_cuts(n, p, K) if partition == "balanced" else uniform_cuts(n, p))
    cf = np.concatenate([[0.0], np.cumsum(fine)])
    cc = np.concatenate([[0.0], np.cumsum(coarse)])
    start = np.where(cuts[:-1] == 0, 0.0, cc[np.minimum(cuts[:-1] + 1, n)] + recovery_s)
    extra = np.append(np.minimum(overlap, np.diff(cuts)[1:]), 0)
    return float(np.max(start + cf[cuts[1:] + extra] - cf[cuts[:-1]]))


def scheduler_predictions(fine: np.ndarray, coarse: np.ndarray, recovery_s: float, scene: str,
                          overlap: int = 0, workers: tuple[int, ...] = SCHEDULER_P) -> list[dict]:
    """Predicted speedup and efficiency for P = 8..512 from measured costs tiled to 16 x 512 steps."""
    n = 16 * max(SCHEDULER_P)
    f, c = np.resize(fine, n), np.resize(coarse, n)
    out = []
    for p in workers:
        for partition in ("uniform", "balanced"):
            speedup = float(f.sum() / simulate_schedule(f, c, recovery_s, p, partition, overlap))
            out.append({"scene": scene, "workers": p, "partition": partition, "predicted_speedup": speedup,
                        "efficiency": speedup / p, "K": float(f.mean() / c.mean()), "steps": n})
    return out


def plot_scheduler(predictions: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for scene in sorted({r["scene"] for r in predictions}):
        for partition, style in (("uniform", "--"), ("balanced", "-")):
            rows = [r for r in predictions if r["scene"] == scene and r["partition"] == partition]
            P = [r["workers"] for r in rows]
            axes[0].plot(P, [r["predicted_speedup"] for r in rows], style, marker="o", label=f"{scene} {partition}")
            axes[1].plot(P, [r["efficiency"] for r in rows], style, marker="o", label=f"{scene} {partition}")
            if partition == "balanced":
                K = rows[0]["K"]
                axes[0].plot(P, [speedup_bounds(K, p)["balanced"] for p in P], ":", color="gray")
    axes[0].set(xscale="log", yscale="log", xlabel="workers P", ylabel="predicted speedup",
                title="scheduler simulation (dotted: K(1-(1-1/K)^P))")
    plain = matplotlib.ticker.ScalarFormatter()  # 2.5, not 2.5 x 10^0, on a log axis spanning less than a decade
    axes[0].yaxis.set_major_formatter(plain)
    axes[0].yaxis.set_minor_formatter(plain)
    axes[1].set(xscale="log", xlabel="workers P", ylabel="efficiency (speedup / P)")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)


POP_MM = 8.0  # top of the colour scale of the boundary picture


def render_boundary(scene: Scene, hier: Hierarchy, result, states: np.ndarray, path: Path) -> None:
    """The garment around the first segment boundary, labelled: rows are the serial run,
    the joined time-parallel run (cross-faded) and the segments' own frames (as with
    --crossfade 0), the latter two coloured by each vertex's extra motion since the
    previous frame against the serial run (the pop); columns the frame before the
    boundary, the first after it, and two frames later in the cross-fade."""
    from PIL import Image, ImageDraw

    from tryon.drape.outputs import SKIN
    from tryon.render.appearance import appearance
    from tryon.render.colormap import add_colorbar, scalar_to_rgb
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes, save_png

    segs = result.segments
    k = next((i for i, s in enumerate(segs) if s.x_upsampled is not None), None)
    if k is None:  # every later segment was restarted from its predecessor: no boundary to show
        return
    seg = segs[k]
    steps, own = plain_join(hier, segs)
    plain, joined = dict(zip(steps, own)), dict(zip(steps, result.positions))
    first = int(np.searchsorted(steps, seg.start + 1))
    span = result.summary["parallel"]["crossfade"]["steps"]
    last = min(int(np.searchsorted(steps, seg.start + span)), len(steps) - 1)
    columns = sorted({first - 1, first, (first + last) // 2, last})
    rows = [("serial run", None), ("time-parallel, cross-faded", joined), ("segments' own frames (no cross-fade)", plain)]
    faces = scene.model.faces.numpy()
    cam = Camera.fit([states[seg.start]], "three_quarter", aspect=0.75, margin=1.25)
    grid = []
    for label, frames in rows:
        panels = []
        for i in columns:
            step, before = steps[i], steps[i - 1]
            body = scene.model.obstacles.vertices_at(step * scene.dt)
            if frames is None:
                cloth = RenderMesh(states[step], faces, color=appearance(scene.model.fabric.name).color)
            else:
                extra = np.linalg.norm((frames[step] - frames[before]) - (states[step] - states[before]), axis=1)
                cloth = RenderMesh(frames[step], faces, vertex_colors=scalar_to_rgb(1000 * extra, 0.0, POP_MM, "magma"))
            img = render_meshes([RenderMesh(body, scene.model.obstacles.faces, color=SKIN, two_sided=False), cloth],
                                300, 400, camera=cam)
            pil = Image.fromarray(img)
            where = "boundary" if step == seg.start else f"{step - seg.start:+d} steps from the boundary"
            ImageDraw.Draw(pil).text((10, 8), f"{label}\nstep {step} ({where})", fill=(30, 30, 30))
            panels.append(np.asarray(pil))
        grid.append(np.concatenate(panels, axis=1))
    picture = add_colorbar(np.concatenate(grid, axis=0), 0.0, POP_MM, "magma",
                           label="extra motion (mm)")
    save_png(path, picture)


def run_parallel_bench(json_path: str, quick: bool = False, workers: list[int] | None = None,
                       only: list[str] | None = None) -> list[dict]:
    """Run the benchmark (the scenes in `only`, default all), print a table and write the
    records, the K probes at 1 cm and 0.5 cm (with the walk; not with --quick) and two
    PNGs next to json_path."""
    from tryon.parallel.executors import connect_ray

    workers = sorted(set(workers or [1, 2]))
    if workers[0] < 1:
        from tryon.errors import TryonError

        raise TryonError(f"--workers must be at least 1, got {workers[0]}")
    json_path = Path(json_path)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    started = connect_ray(None, max(workers))
    records, predictions = [], []
    try:
        for scene in bench_scenes(quick, only):
            hier = build_hierarchy(scene)
            with worker_threads():  # the serial baseline on as many threads as one worker
                states, fine_costs = serial_run(scene)
                twin, _ = serial_run(scene, perturb=SPREAD_PERTURBATION)
                coarse = coarse_costs(hier)
            serial_s = float(fine_costs.sum())
            last = None
            for p in workers:
                for partition in (["adaptive", "uniform", "balanced"] if p == max(workers) and p > 1 else ["adaptive"]):
                    rec, res = parallel_record(scene, hier, states, serial_s, p, partition, twin)
                    records.append(rec)
                    last = res if p > 1 and partition == "uniform" else last
                    _print(rec)
            recov = [b["setup_s"] for r in records if r["scene"] == scene.name for b in r["boundaries"]]
            overlap = int(round(ParallelOptions().crossfade / scene.dt))
            predictions += scheduler_predictions(fine_costs, coarse, _mean(recov) or 0.0, scene.name, overlap)
            if scene.spec and "animation" in scene.spec and last is not None:
                render_boundary(scene, hier, last, states, json_path.with_name(json_path.stem + "-boundary.png"))
    finally:
        if started:
            import ray

            ray.shutdown()
    probes = [] if quick or (only and "animate-walk" not in only) else k_probes("walk", recovery_s=_walk_start_up(records))
    for r in probes:
        print(f"  K probe {r['scene']} at {r['edge_length'] * 100:g} cm: {r['fine_vertices']} / {r['coarse_vertices']} "
              f"vertices, K {r['K']:.1f}; predicted speedup at P={r['projected_workers']}: {r['projected_speedup']:.1f} "
              f"({100 * r['projected_share_of_K']:.0f} % of K)")
    plot_scheduler(predictions, json_path.with_name(json_path.stem + "-scheduler.png"))
    for r in predictions:
        if r["partition"] == "balanced":
            print(f"  predicted {r['scene']:<22} P={r['workers']:<4} speedup {r['predicted_speedup']:7.1f}  "
                  f"efficiency {r['efficiency']:.2f}")
    payload = {"records": records, "scheduler": predictions, "k_probes": probes, "cpu_count": os.cpu_count(),
               "note": "speedups measured on this machine are limited by its CPU cores (shared with other work)"}
    with atomic_write(json_path) as fh:
        fh.write(dumps_json(payload, indent=2))
    return records


def _walk_start_up(records: list[dict]) -> float | None:
    """Mean measured segment start-up (s) of the walk's runs, if any ran."""
    return _mean([b["setup_s"] for r in records if r["scene"] == "animate-walk" for b in r["boundaries"]])


def _print(r: dict) -> None:
    fmt = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    print(f"{r['scene']:<22} P={r['workers']} {r['partition']:<9} K={fmt(r['K'])} serial {r['serial_s']:.1f} s "
          f"parallel {r['parallel_s']:.1f} s speedup {fmt(r['speedup'])} (bounds {fmt(r['bound_uniform'])} / "
          f"{fmt(r['bound_balanced'])}) curvature error {fmt(r['curvature_error_before'])} -> "
          f"{fmt(r['curvature_error_after'])} (exact coarse shape: {fmt(r['curvature_error_exact_coarse_before'])} -> "
          f"{fmt(r['curvature_error_exact_coarse_after'])}, 10 iterations "
          f"{fmt(r['curvature_error_exact_coarse_after_10_iterations'])}; the serial run's twin "
          f"({SPREAD_PERTURBATION * 1e6:g} um start noise): "
          f"{fmt(r['curvature_error_serial_spread'])}); boundary jump {fmt(r['boundary_jump_mm'])} mm "
          f"(serial step {fmt(r['serial_step_mm'])} mm); pop per frame {fmt(r['pop_plain_mm'])} -> "
          f"{fmt(r['pop_crossfade_mm'])} mm cross-faded (elsewhere {fmt(r['pop_baseline_mm'])}, serial motion "
          f"{fmt(r['serial_frame_mm'])} mm/frame)")
