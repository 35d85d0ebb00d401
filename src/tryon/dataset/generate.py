"""Running a dataset generator: in this process or as Ray tasks, streaming finished
samples into shards, resuming where a stopped run left off.

A generator is a module-level pair of functions: `prepare(manifest, folder)` builds what
every sample shares (run once, in the driver; its result must pickle) and
`make(manifest, shared, unit)` makes one sample. Samples are drawn per unit from the
manifest's seed, so the order in which units finish does not change the data.

Every simulation of a generator uses the linear solver `DATASET_LINEAR_SOLVER`, whatever
the simulator's default, so that a dataset grown over many runs and software versions
holds samples of one solve. Change it only with new generator versions: it changes the
samples (the iterative solve stops at a tolerance, and contact-rich drapes amplify the
difference into other folds).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from tryon.dataset.store import DatasetError, Manifest, ShardStore
from tryon.io.atomic import check_output_dir, claim_work_dir, is_owned
from tryon.io.json_safe import write_json
from tryon.sim.linear import auto_solver_pinned

Prepare = Callable[[Manifest, Path], object]
Make = Callable[[Manifest, object, int], dict]

DATASET_LINEAR_SOLVER = "pcg"  # block-Jacobi PCG: what every dataset in data/ was made with


@dataclass
class RunReport:
    made: int
    skipped: int
    failed: int
    wall_s: float
    sample_s: float      # summed seconds of the samples made (a core each)
    workers: int

    @property
    def samples_per_core_hour(self) -> float:
        return 3600.0 * self.made / self.sample_s if self.sample_s > 0 else 0.0


def open_dataset(folder: str | Path, manifest: Manifest, force: bool = False) -> ShardStore:
    """Create the dataset folder, or reopen it to resume: an existing dataset must have
    been made with the same settings (it may grow: a larger count adds units)."""
    folder = check_output_dir(folder, force=force)
    if (folder / "manifest.json").exists() and is_owned(folder):
        old = Manifest.read(folder)
        diff = old.same_data(manifest)
        if diff:
            raise DatasetError(f"{folder} holds a dataset made with other settings ({', '.join(diff)} differ); "
                               "choose another --out, or repeat that dataset's settings to resume it")
        manifest.created = old.created
        manifest.count = max(manifest.count, old.count)
        claim_work_dir(folder, resume=True)
    else:
        claim_work_dir(folder, resume=False, force=force)
    store = ShardStore(folder, manifest)
    store.write_manifest()
    stranded = store.remove_stranded_samples()
    if stranded:
        print(f"removed {stranded} pending sample file(s) their shard already holds (left by a stopped run)")
    store.reopen_short_shards()
    return store


def run_generator(store: ShardStore, prepare: Prepare, make: Make, workers: int = 1, ray_address: str | None = None,
                  progress: bool = True, limit: int | None = None) -> RunReport:
    """Make every missing unit (at most `limit` of them) and store it; `workers` > 1 or an
    address runs the units as Ray tasks, one CPU each."""
    t0 = time.perf_counter()
    done = store.done_units()
    todo = [u for u in range(store.manifest.count) if u not in done]
    if limit is not None:
        todo = todo[:limit]
    with auto_solver_pinned(DATASET_LINEAR_SOLVER):
        shared = prepare(store.manifest, store.folder)
    bar = tqdm(total=store.manifest.count, initial=len(done), desc=f"{store.manifest.kind} samples", unit="sample",
               disable=not progress)
    made = failed = 0
    sample_s = 0.0

    def keep(unit: int, sample: dict) -> None:
        nonlocal made, failed, sample_s
        store.put(unit, sample)
        made += 1
        failed += int(not bool(sample.get("ok", True)))
        sample_s += float(sample.get("wall_s", 0.0))
        bar.update(1)
        bar.set_postfix(failed=failed, per_core_hour=f"{3600 * made / max(sample_s, 1e-9):.0f}")

    try:
        if workers <= 1 and not ray_address:
            for unit in todo:
                keep(unit, _task(make, store.manifest, shared, unit, one_thread=False)[1])
        else:
            _run_on_ray(store.manifest, shared, make, todo, workers, ray_address, keep)
    finally:
        bar.close()
    for k in range(store.num_shards()):  # shards whose last samples came from an earlier run
        store.pack(k)
    report = RunReport(made, len(done), failed, time.perf_counter() - t0, sample_s, workers)
    write_json(store.folder / "last_run.json", {**report.__dict__, "samples_per_core_hour": report.samples_per_core_hour})
    return report


def _task(make: Make, manifest: Manifest, shared: object, unit: int, one_thread: bool = True) -> tuple[int, dict]:
    """One unit's sample, made with the datasets' linear solver (on one thread in a Ray worker)."""
    if one_thread:
        from tryon.parallel.executors import one_thread_per_worker

        one_thread_per_worker()
    with auto_solver_pinned(DATASET_LINEAR_SOLVER):
        return unit, make(manifest, shared, unit)


def _run_on_ray(manifest: Manifest, shared: object, make: Make, todo: list[int], workers: int,
                ray_address: str | None, keep: Callable[[int, dict], None]) -> None:
    from tryon.parallel.executors import connect_ray

    started = connect_ray(ray_address, workers)
    import ray

    try:
        task = ray.remote(num_cpus=1, max_retries=2)(_task)
        shared_ref, manifest_ref = ray.put(shared), ray.put(manifest)
        queue, running = list(todo), []
        in_flight = 2 * max(workers, int(ray.cluster_resources().get("CPU", workers)))
        while queue or running:
            while queue and len(running) < in_flight:
                running.append(task.remote(make, manifest_ref, shared_ref, queue.pop(0)))
            ready, running = ray.wait(running, num_returns=1)
            for ref in ready:
                unit, sample = ray.get(ref)
                keep(unit, sample)
    finally:
        if started:
            ray.shutdown()


def default_workers() -> int:
    return max(1, (os.cpu_count() or 1))
