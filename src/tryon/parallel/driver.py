"""Time-domain parallel simulation of a `Scene` (Liang & Lin, SCA 2018).

The driver runs the coarse simulation step by step in this process. Whenever the coarse
run reaches a partition point s_j (and one coarse step beyond it, for the recovery's
coarse change), it launches fine segment j, which recovers the fine detail (Algorithm 3)
and simulates steps s_j..s_{j+1}. Segment 0 starts at once from the scene's exact initial
state. With the adaptive partition (Algorithm 2) the cut s_{j+1} is decided online, while
segment j already runs, from the measured coarse and fine costs. Every segment but the
last runs `crossfade` seconds past its end, and the join cross-fades those frames with
the next segment's first ones (`join`), so the boundaries do not pop. Segments stream
back as they finish and are joined into the frames a serial fine run would keep.

Checkpoints (`checkpoint_dir`): the partition, every finished segment, the coarse states
each launched segment started from and the coarse run's latest state. A stopped run
resumed with `resume=True` keeps its finished segments and re-runs only the others.
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tryon.errors import TryonError
from tryon.io.atomic import atomic_write, check_output_dir, claim_work_dir
from tryon.parallel.coarse import CoarseRun
from tryon.parallel.executors import LocalExecutor, Progress, RayExecutor, worker_threads
from tryon.parallel.hierarchy import Hierarchy, build_hierarchy
from tryon.parallel.join import join_with_crossfade
from tryon.parallel.partition import PARTITIONS, AdaptivePartitioner, balanced_cuts, speedup_bounds, uniform_cuts
from tryon.parallel.recovery import RecoveryOptions
from tryon.parallel.segment import SegmentResult, SegmentSpec
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.loop import run
from tryon.sim.metrics import state_metrics
from tryon.sim.runner import RunResult, ScenePicture, publish_run
from tryon.sim.scene import Scene

MODES = ("ray", "local")
log = logging.getLogger(__name__)


@dataclass
class ParallelOptions:
    """How to split a run. `segments` defaults to `workers`; `level` picks the hierarchy
    ('auto', 'coarsen' by `factor`, 'subdivide'; see `build_hierarchy`); the coarse run
    steps `dt_ratio` fine steps at once (None: 4 for garment animations, else 1) and
    (garments) may collide with a body proxy of `obstacle_cell` metres (see
    `build_hierarchy`); `K` (fine/coarse cost per step) fixes the
    balanced partition, else a short probe measures it. `crossfade` (seconds) is how long
    each segment runs past its end for the join's cross-fade (0: segments meet in one
    frame)."""

    workers: int = 2
    partition: str = "adaptive"
    segments: int | None = None
    level: str = "auto"
    factor: float | None = None
    dt_ratio: int | None = None
    obstacle_cell: float | str | None = "auto"
    recovery: RecoveryOptions = field(default_factory=RecoveryOptions)
    crossfade: float = 0.2
    K: float | None = None
    mode: str = "ray"
    ray_address: str | None = None
    max_attempts: int = 3
    object_store_mb: int = 256

    def validate(self) -> None:
        if self.workers < 1:
            raise TryonError(f"--workers must be at least 1, got {self.workers}")
        if self.partition not in PARTITIONS:
            raise TryonError(f"unknown partition {self.partition!r}; use one of {', '.join(PARTITIONS)}")
        if self.mode not in MODES:
            raise TryonError(f"unknown parallel mode {self.mode!r}; use 'ray' or 'local'")
        if self.segments is not None and self.segments < 1:
            raise TryonError(f"segments must be at least 1, got {self.segments}")
        if self.K is not None and not self.K > 0:
            raise TryonError(f"the cost ratio K must be positive, got {self.K}")
        if self.dt_ratio is not None and (int(self.dt_ratio) != self.dt_ratio or self.dt_ratio < 1):
            raise TryonError(f"--coarse-dt-ratio must be a whole number of fine steps, at least 1, got {self.dt_ratio}")
        if not self.crossfade >= 0:
            raise TryonError(f"--crossfade must be a duration in seconds, 0 or more, got {self.crossfade}")
        if self.max_attempts < 1:
            raise TryonError(f"max_attempts must be at least 1, got {self.max_attempts}")
        self.recovery.validate()

    @property
    def num_segments(self) -> int:
        return self.segments or self.workers

    def result_key(self) -> dict:
        """The options that change the frames (a checkpoint must match them)."""
        return {"partition": self.partition, "segments": self.num_segments, "level": self.level, "factor": self.factor,
                "dt_ratio": self.dt_ratio, "obstacle_cell": self.obstacle_cell, "recovery": asdict(self.recovery),
                "crossfade": self.crossfade}


def probe_cost_ratio(hier: Hierarchy, steps: int = 2) -> dict:
    """K from a few timed steps of both levels from the initial state (after one untimed
    step each for JIT and solver set-up): fine seconds per step / coarse seconds per fine
    step. Used by the static balanced partition, which needs K before the run."""
    def timed(scene) -> float:
        solver = ImplicitEulerSolver(scene.model, scene.options)
        warm = run(solver, scene.model.initial_state(), scene.dt, until=1)
        tic = time.perf_counter()
        run(solver, warm.state, scene.dt, until=1 + steps, start=1)
        return (time.perf_counter() - tic) / steps

    fine = timed(hier.fine)
    coarse = timed(hier.coarse) / hier.dt_ratio
    return {"fine_s_per_step": fine, "coarse_s_per_fine_step": coarse, "K": fine / coarse}


class _Checkpoint:
    """Files under `<folder>/parallel/`: manifest.json, segment_<index>.npz, coarse_<step>.npz
    (states a segment started from), coarse_last.npz."""

    def __init__(self, folder: Path | None, fingerprint: str, key: dict):
        self.dir = None if folder is None else Path(folder) / "parallel"
        self.fingerprint = fingerprint
        self.key = key
        if self.dir is not None:
            self.dir.mkdir(parents=True, exist_ok=True)

    def _npz(self, name: str, arrays: dict) -> None:
        if self.dir is not None:
            with atomic_write(self.dir / name, "wb") as fh:
                np.savez(fh, **arrays)

    def save_manifest(self, cuts: list[int], history: list[dict]) -> None:
        if self.dir is not None:
            with atomic_write(self.dir / "manifest.json") as fh:
                json.dump({"fingerprint": self.fingerprint, "key": self.key, "cuts": cuts, "history": history}, fh)

    def save_segment(self, res: SegmentResult) -> None:
        self._npz(f"segment_{res.index:04d}.npz", res.to_arrays())

    def save_coarse(self, name: str, states: dict[int, tuple[np.ndarray, np.ndarray]], steps: list[int]) -> None:
        steps = [s for s in steps if s in states]
        self._npz(name, {"steps": np.asarray(steps, np.int64), "x": np.stack([states[s][0] for s in steps]),
                         "v": np.stack([states[s][1] for s in steps])})

    def load(self) -> tuple[dict, dict[int, tuple], dict[int, SegmentResult]] | None:
        """(manifest, coarse states, finished segments) of a matching earlier run, or None."""
        if self.dir is None or not (self.dir / "manifest.json").exists():
            return None
        manifest = json.loads((self.dir / "manifest.json").read_text())
        if manifest.get("fingerprint") != self.fingerprint or manifest.get("key") != json.loads(json.dumps(self.key)):
            return None
        states: dict[int, tuple] = {}
        for f in sorted(self.dir.glob("coarse_*.npz")):
            with np.load(f) as a:
                states.update(CoarseRun.trajectory_from(a))
        done = {}
        for f in sorted(self.dir.glob("segment_*.npz")):
            with np.load(f) as a:
                res = SegmentResult.from_arrays({k: a[k] for k in a.files})
            done[res.index] = res
        return manifest, states, done


class _Driver:
    def __init__(self, hier: Hierarchy, opts: ParallelOptions, progress: bool, checkpoint_dir: Path | None,
                 resume: bool, on_progress: Callable[[Progress], None] | None):
        self.hier, self.opts = hier, opts
        fine = hier.fine
        self.N, self.r, self.per_frame = fine.num_steps, hier.dt_ratio, fine.steps_per_frame
        self.overlap = int(round(opts.crossfade / fine.dt))
        self.ckpt = _Checkpoint(checkpoint_dir, hier.fingerprint(), opts.result_key())
        self.on_progress = on_progress
        self.done: dict[int, SegmentResult] = {}
        self.launched: set[int] = set()
        self.to_restart: dict[int, int] = {}  # segment -> crossings in its recovered start (see _finish)
        self.probe: dict | None = None
        loaded = self.ckpt.load() if resume else None
        trajectory = None
        if loaded is not None:
            manifest, trajectory, self.done = loaded
        self.coarse = CoarseRun(hier, trajectory)
        self.partitioner = self._partitioner(loaded[0] if loaded else None)
        self.ckpt.save_manifest(self.partitioner.cuts, self.partitioner.history)
        self.resumed_segments = sorted(self.done)
        self.bar = tqdm(total=self.N, desc=f"time-parallel {fine.name}", unit="step", disable=not progress, leave=False)

    # ------------------------------------------------------------------ partition
    def _partitioner(self, manifest: dict | None) -> AdaptivePartitioner:
        p, N, r = self.opts.num_segments, self.N, self.r
        part = AdaptivePartitioner(N, p, multiple=r, prior_K=self._prior_K())
        if manifest is not None:
            part.cuts, part.history = list(manifest["cuts"]), list(manifest["history"])
            return part
        if self.opts.partition == "uniform":
            part.cuts = uniform_cuts(N, p, r)
        elif self.opts.partition == "balanced":
            K = self.opts.K
            if K is None and p > 1:
                self.probe = probe_cost_ratio(self.hier)
                K = self.probe["K"]
            part.cuts = balanced_cuts(N, p, K or 1.0, r)
            part.history = [{"K": K}]
        return part

    def _prior_K(self) -> float:
        """Before any fine step is measured: cost proportional to vertices and steps."""
        nf, nc = self.hier.fine.model.num_vertices, self.hier.coarse.model.num_vertices
        return max(1.5, nf / nc * self.r)

    def _coarse_target(self) -> int:
        """How far the coarse run must go: one coarse step past the last segment start, or
        to the end while the adaptive partition is still open."""
        cuts = self.partitioner.cuts
        if not self.partitioner.done:
            return max(self.N, cuts[-1] + self.r)
        starts = cuts[:-1]
        return 0 if starts == [0] else max(starts) + self.r

    # ------------------------------------------------------------------ loop
    def run(self, executor) -> list[SegmentResult]:
        self._executor_table = executor.table
        executor.table.listener = self._progress
        try:
            while len(self.done) < self._segment_count():
                stepped = self._advance_coarse()
                self._decide_cut(executor)
                self._launch_ready(executor)
                self._launch_restarts(executor)
                for res in executor.poll(self.coarse.position, timeout=0.0 if stepped else 0.05):
                    self._finish(res)
        finally:
            self.bar.close()
        return [self.done[j] for j in sorted(self.done)]

    def _segment_count(self) -> int:
        cuts = self.partitioner.cuts
        return len(cuts) - 1 if self.partitioner.done else len(cuts) + 1

    def _advance_coarse(self) -> bool:
        if self.coarse.position >= self._coarse_target():
            return False
        self.coarse.advance()
        if len(self.coarse.seconds) % 25 == 0:
            self.ckpt.save_coarse("coarse_last.npz", self.coarse.states, [self.coarse.position])
        return True

    def _decide_cut(self, executor) -> None:
        part = self.partitioner
        if part.done or self.opts.partition != "adaptive":
            return
        open_segment = len(part.cuts) - 1
        cut = part.offer(self.coarse.position, self.coarse.cost_per_fine_step(), executor.table.fine_cost())
        if cut is None:
            return
        executor.set_end(open_segment, cut)
        if part.done and len(part.cuts) - 1 > open_segment + 1:
            executor.set_end(open_segment + 1, part.cuts[-1])
        self.ckpt.save_manifest(part.cuts, part.history)

    def _launch_ready(self, executor) -> None:
        cuts = self.partitioner.cuts
        for j, start in enumerate(cuts):
            if start >= self.N or j in self.launched or j in self.done or not self.coarse.has_start(start):
                continue
            end = cuts[j + 1] if j + 1 < len(cuts) else None
            coarse = None if start == 0 else self.coarse.start_pair(start)
            if start > 0:
                self.ckpt.save_coarse(f"coarse_{start:06d}.npz", self.coarse.states, [start, start + self.r])
            # the cross-fade needs no more than the next segment's length, where that is known
            overlap = min(self.overlap, cuts[j + 2] - cuts[j + 1]) if j + 2 < len(cuts) else self.overlap
            executor.submit(SegmentSpec(j, start, end, self.N, self.per_frame, coarse, self.opts.recovery, overlap))
            self.launched.add(j)

    def _launch_restarts(self, executor) -> None:
        """Segments whose recovered start crossed itself or an obstacle run again from the
        state the previous segment arrived at, once it has finished: the joined run then
        has no crossing, as a serial run has none, at the cost of that segment's parallelism."""
        cuts = self.partitioner.cuts
        for j in sorted(self.to_restart):
            prev = self.done.get(j - 1)
            if prev is None:
                continue
            end = cuts[j + 1] if j + 1 < len(cuts) else None
            overlap = min(self.overlap, cuts[j + 2] - cuts[j + 1]) if j + 2 < len(cuts) else self.overlap
            crossings = self.to_restart.pop(j)
            log.warning("time-parallel segment %d starts through itself or the body (%d crossings after recovery): "
                        "running it from segment %d's state at step %d", j, crossings, j - 1, cuts[j])
            executor.submit(SegmentSpec(j, cuts[j], end, self.N, self.per_frame, None, self.opts.recovery, overlap,
                                        exact=(prev.x_end, prev.v_end), refused_crossings=crossings))

    def _finish(self, res: SegmentResult) -> None:
        if res.start_crossings:
            self.to_restart[res.index] = res.start_crossings
            return
        self.done[res.index] = res
        self.ckpt.save_segment(res)

    def _progress(self, p: Progress) -> None:
        cuts = self.partitioner.cuts
        latest = self._executor_table.latest
        running = sum(max(0, q.step - cuts[q.index]) for j, q in latest.items() if j not in self.done and j < len(cuts))
        finished = sum(r.end - r.start for r in self.done.values())
        self.bar.n = min(self.N, running + finished)
        self.bar.refresh()
        if self.on_progress is not None:
            self.on_progress(p)


# ---------------------------------------------------------------------------- public API

@dataclass
class ParallelRunResult(RunResult):
    """A serial-format `RunResult` of the fine cloth plus the segments it was joined from."""

    segments: list[SegmentResult] = field(default_factory=list)
    hierarchy: Hierarchy | None = None


def simulate_time_parallel(
    scene: Scene,
    options: ParallelOptions | None = None,
    progress: bool = True,
    checkpoint_dir: Path | None = None,
    resume: bool = False,
    on_progress: Callable[[Progress], None] | None = None,
    hierarchy: Hierarchy | None = None,
) -> ParallelRunResult:
    """Simulate the fine level of `scene` time-parallel; frames match a serial fine run's."""
    opts = options or ParallelOptions()
    opts.validate()
    hier = hierarchy or build_hierarchy(scene, opts.level, opts.factor, opts.dt_ratio, opts.obstacle_cell)
    uniform_cuts(hier.fine.num_steps, opts.num_segments, hier.dt_ratio)  # enough steps for the segments?
    if opts.mode == "local":
        executor, startup = LocalExecutor(hier), 0.0
    else:
        executor = RayExecutor(hier, opts.workers, opts.ray_address, opts.max_attempts, opts.object_store_mb)
        startup = executor.warm_up(opts.workers)
    try:
        wall0 = time.perf_counter()
        driver = _Driver(hier, opts, progress, checkpoint_dir, resume, on_progress)
        # beside Ray workers the coarse run (small: a thread pool gains nothing on it) shares
        # their cores, and more threads would only spin against them; in-process, the
        # segments run here too and keep the process's threads
        with worker_threads() if opts.mode != "local" else nullcontext():
            segments = driver.run(executor)
        wall = time.perf_counter() - wall0
    finally:
        executor.close()
    positions, times, crossfade = join_with_crossfade(hier, segments)
    model = hier.fine.model
    frame_metrics = [state_metrics(model, x, t) for x, t in zip(positions, times)]
    summary = _summary(hier, opts, driver, executor, segments, wall, startup, frame_metrics)
    summary["parallel"]["crossfade"] = {"seconds": opts.crossfade, "steps": driver.overlap,
                                        "blended_frames": {str(k): v for k, v in crossfade.blended.items()},
                                        "replaced_frames": {str(k): v for k, v in crossfade.replaced.items()}}
    return ParallelRunResult(positions, times, summary, frame_metrics, segments=segments, hierarchy=hier)


def _summary(hier: Hierarchy, opts: ParallelOptions, driver: _Driver, executor, segments: list[SegmentResult],
             wall: float, startup: float, fm: list[dict]) -> dict:
    fine, m = hier.fine, hier.fine.model
    n = fine.num_steps
    fine_seconds = [s for seg in segments for s in seg.step_seconds]
    f = float(np.mean(fine_seconds)) if fine_seconds else None
    c = driver.coarse.cost_per_fine_step()
    K = f / c if f and c else None
    p = len(segments)
    parallel = {
        "mode": opts.mode, "workers": opts.workers, "segments": p, "partition": opts.partition,
        "fine_level": hier.kind, "dt_ratio": hier.dt_ratio, "obstacle_proxies": hier.obstacle_proxies,
        "coarse_vertices": hier.coarse.model.num_vertices,
        "cuts": driver.partitioner.cuts, "K": K, "fine_s_per_step": f, "coarse_s_per_fine_step": c,
        "coarse_steps": len(driver.coarse.seconds), "coarse_seconds": float(sum(driver.coarse.seconds)),
        "probe": driver.probe, "adaptive_history": driver.partitioner.history if opts.partition == "adaptive" else [],
        "speedup_bounds": speedup_bounds(K, opts.workers) if K else None,
        "recovery": [{"segment": s.index, **{k: v for k, v in s.recovery.items() if k != "changes"}} for s in segments],
        "segment_seconds": [float(sum(s.step_seconds) + s.setup_seconds) for s in segments],
        "attempts": {str(k): v for k, v in sorted(executor.table.attempts.items())},
        "resubmitted": getattr(executor, "resubmitted", 0), "resumed_segments": driver.resumed_segments,
        "restarted_segments": {str(s.index): {"start_crossings": s.restarted} for s in segments if s.restarted},
        "ray_startup_s": startup, "ray": getattr(executor, "cluster", None),
    }
    return {
        "scene": fine.name, "vertices": m.num_vertices, "faces": int(m.faces.shape[0]), "fabric": m.fabric.name,
        "dt": fine.dt, "duration": fine.duration, "steps": n, "frames": len(fm), "wall_s": wall,
        "s_per_step": wall / max(n, 1), "retried_steps": int(sum(s.retried_steps for s in segments)),
        "fail_safe_used": bool(any(s.fail_safe_used for s in segments)),
        "max_strain": max(x["max_strain"] for x in fm), "final_max_strain": fm[-1]["max_strain"],
        "min_obstacle_distance": min(x["min_obstacle_distance"] for x in fm),
        "intersections": max(x["self_intersections"] + x["obstacle_intersections"] for x in fm),
        "final_intersections": fm[-1]["self_intersections"] + fm[-1]["obstacle_intersections"],
        "finite": bool(all(np.isfinite(x["max_strain"]) for x in fm)),
        "parallel": parallel,
    }


def run_scene_time_parallel(
    scene: Scene,
    out_dir: str | Path,
    workers: int = 2,
    partition: str = "adaptive",
    ray_address: str | None = None,
    mode: str = "ray",
    progress: bool = True,
    resume: bool = False,
    write_objs: bool = True,
    options: ParallelOptions | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    force: bool = False,
    picture: ScenePicture | None = None,
) -> ParallelRunResult:
    """Time-parallel counterpart of `tryon.sim.runner.run_scene`: the same outputs
    (frames.npz, obj/, summary.json, last_frame.png) for the fine cloth, assembled under
    `<out>.partial` (which holds the checkpoint) and renamed into place when complete.
    `options`, when given, overrides workers / partition / ray_address / mode."""
    opts = options or ParallelOptions(workers=workers, partition=partition, ray_address=ray_address, mode=mode)
    out_dir = check_output_dir(out_dir, force=force)
    work = claim_work_dir(out_dir.with_name(out_dir.name + ".partial"), resume=resume, force=force)
    result = simulate_time_parallel(scene, opts, progress=progress, checkpoint_dir=work, resume=resume,
                                    on_progress=on_progress)
    shutil.rmtree(work / "parallel", ignore_errors=True)
    publish_run(work, out_dir, result.hierarchy.fine, result, write_objs, picture, force)
    return result
