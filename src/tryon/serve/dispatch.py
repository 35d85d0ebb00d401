"""The dispatcher: a thread in the server that hands the fits' phases to workers, and
keeps every job accounted for when a worker dies or a job runs too long.

Two lanes, so a first answer never waits behind a refinement:
- the answer lane (`answer` phases: a fraction of a second each) at normal priority;
- the work lane (`refine` and `simulate`: seconds to minutes), whose local workers run at
  a lower priority (`jobs.REFINE_NICENESS`), so they take only the processor time the
  answers leave. Ray tasks are not niced: a Ray worker process is reused by any task.

Each lane's workers are local processes (spawned), or Ray tasks on an existing cluster
(`--ray-address`; the cluster's nodes must see `--data`, e.g. the same machine or a
shared disk). A local worker that dies (killed, out of memory) breaks its pool: every job
the pool held and did not finish goes back to its queue (`Store.requeue_or_fail`, a try
spent) and a fresh pool starts; a Ray task whose worker dies is queued again the same way.
A job past the time limit fails with that reason and is stopped (its local pool replaced,
the others of that pool queued again with their tries given back, or its Ray task
cancelled; on Ray the limit counts from the hand-over, queueing on the cluster included).
Every few seconds each lane sweeps back any claim no worker holds.
"""

from __future__ import annotations

import multiprocessing
import shutil
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from tryon.serve.jobs import REFINE_NICENESS, body_path, fit_folder, run_phase
from tryon.serve.store import Store

# the dispatcher wakes when a fit is posted or a job ends; else it looks at the queue this often
IDLE_POLL_S = 0.5
PRUNE_EVERY_S = 60.0
SWEEP_EVERY_S = 5.0
ANSWER_TIME_LIMIT_S = 120.0


def _warm_up(niceness: int) -> None:
    """Run in each new local worker: one thread (the workers share the cores; threads of
    one worker that wait on each other spin when it gets less than their count), a lower
    priority if asked, and what a phase needs imported and loaded before the first job. An
    answer worker (niceness 0) also fits a body and answers a fit once, so its compiled
    kernels are ready before the first shopper's (a cold first answer takes seconds)."""
    import os

    from tryon.parallel.executors import one_thread_per_worker

    one_thread_per_worker()

    if niceness:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, niceness)
        except (AttributeError, OSError):
            pass
    import tryon.serve.jobs  # noqa: F401
    from tryon.body.anny_model import body_model
    from tryon.sizing.quick import shipped_model

    body_model()
    try:
        shipped_model("tshirt")
        if not niceness:
            _answer_once()
    except Exception:  # noqa: BLE001 - a missing model is reported by the job that needs it
        pass


def _answer_once() -> None:
    from tryon.body.amortised import quick_fit
    from tryon.body.fit import Measurements
    from tryon.io.threads import one_torch_thread
    from tryon.fabric import load_fabric
    from tryon.sizing.quick import first_answer

    with one_torch_thread():
        person = quick_fit(Measurements(height_cm=170.0, weight_kg=65.0, gender="female"))
        first_answer(person, "female", "tshirt", fabric=load_fabric("gray-interlock"))


def _started() -> int:
    """A job that returns (its worker's process id) once its worker has warmed up."""
    import os

    time.sleep(0.2)  # held long enough that each of the first jobs goes to a worker of its own
    return os.getpid()


class LocalWorkers:
    """A pool of spawned worker processes."""

    def __init__(self, workers: int, niceness: int):
        self.workers, self.niceness = workers, niceness
        self.pool = self._new()

    def _new(self) -> ProcessPoolExecutor:
        pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=_warm_up,
                                   initargs=(self.niceness,))
        # the pool starts a process per job when none is idle: start them all now, warmed up
        self.warming = [pool.submit(_started) for _ in range(self.workers)]
        return pool

    def warm(self) -> bool:
        """Whether every worker has warmed up (their first jobs would not wait for it)."""
        if not all(f.done() for f in self.warming):
            return False
        pids = {f.result() for f in self.warming if not f.cancelled() and f.exception() is None}
        if len(pids) < self.workers:  # one worker took two of the probes: ask the others again
            try:
                self.warming = [self.pool.submit(_started) for _ in range(self.workers)]
            except Exception:  # noqa: BLE001 - a pool being replaced: not warm yet
                pass
            return False
        return True

    def submit(self, *args) -> Future:
        return self.pool.submit(run_phase, *args)

    def call(self, fn, *args) -> Future:
        """`fn(*args)` in one of the workers, beside the phases."""
        return self.pool.submit(fn, *args)

    def stop(self, futures: list[Future]) -> bool:
        """Stop these jobs; True when every other job of the pool was stopped with them."""
        self.restart()
        return True

    def forget(self, fut: Future) -> None:
        pass

    def restart(self) -> None:
        self.close()
        self.pool = self._new()

    def close(self) -> None:
        for p in list((getattr(self.pool, "_processes", None) or {}).values()):
            p.kill()
        self.pool.shutdown(wait=False, cancel_futures=True)

    def pids(self) -> list[int]:
        """The workers' process ids (asked from another thread: the pool may be replaced
        meanwhile, so a copy of its table is read, once more if it changed under us)."""
        for _ in range(3):
            try:
                return [p.pid for p in list((getattr(self.pool, "_processes", None) or {}).values())]
            except RuntimeError:  # the table changed while it was copied
                continue
        return []


class RayWorkers:
    """Ray tasks (one CPU each) on the cluster the server joined."""

    def __init__(self, workers: int, niceness: int):
        import ray

        self.workers, self.refs = workers, {}
        self.task = ray.remote(num_cpus=1, max_retries=0)(run_phase)
        self._remote: dict = {}  # function -> its Ray task, wrapped once (each wrapping ships the function again)

    def submit(self, *args) -> Future:
        ref = self.task.remote(*args)
        fut = ref.future()
        self.refs[fut] = ref
        return fut

    def warm(self) -> bool:
        return True

    def call(self, fn, *args) -> Future:
        import ray

        if fn not in self._remote:
            self._remote[fn] = ray.remote(num_cpus=1, max_retries=1)(fn)
        return self._remote[fn].remote(*args).future()

    def stop(self, futures: list[Future]) -> bool:
        import ray

        for fut in futures:
            ref = self.refs.pop(fut, None)
            if ref is not None:
                ray.cancel(ref, force=True)
        return False

    def forget(self, fut: Future) -> None:
        self.refs.pop(fut, None)

    def restart(self) -> None:
        pass

    def close(self) -> None:
        self.stop(list(self.refs))

    def pids(self) -> list[int]:
        return []


class Job:
    """A phase of a fit in a worker's hands."""

    def __init__(self, phase: str, future: Future):
        self.phase, self.future, self.started = phase, future, time.time()

    def finished_itself(self) -> bool:
        """The worker returned (run_phase wrote the outcome; a job's own error fails the
        fit there): nothing for the dispatcher to do."""
        return self.future.done() and not self.future.cancelled() and self.future.exception() is None


class Lane:
    """Workers that run some phases, and the jobs they hold."""

    def __init__(self, name: str, phases: tuple[str, ...], workers, store: Store, data: Path, time_limit_s: float,
                 events: dict, wake: threading.Event | None = None):
        self.name, self.phases, self.workers = name, phases, workers
        self.store, self.data, self.time_limit_s, self.events = store, data, time_limit_s, events
        self.wake = wake or threading.Event()  # set when a job of this lane ends
        self.running: dict[str, Job] = {}

    def fill(self) -> int:
        """Claim and hand over waiting phases while a worker is free; how many."""
        handed = 0
        while len(self.running) < self.workers.workers:
            claimed = self.store.claim_next(self.phases)
            if claimed is None:
                return handed
            handed += 1
            fit_id, phase = claimed
            try:
                fut = self.workers.submit(str(self.store.path), str(self.data), fit_id, phase)
            except Exception:  # noqa: BLE001 - a broken pool, a lost cluster: not this job's fault
                self.store.requeue_or_fail(fit_id, "its workers could not take it", phase, charge=False)
                self.restart()
                return handed
            fut.add_done_callback(lambda _: self.wake.set())
            self.running[fit_id] = Job(phase, fut)
        return handed

    def collect(self) -> int:
        """Take in the jobs that ended; how many."""
        broken, ended = False, 0
        for fit_id, job in list(self.running.items()):
            if not job.future.done():
                continue
            ended += 1
            if not job.finished_itself():
                # run_phase catches the job's own errors: anything raised here is the worker's end
                exc = None if job.future.cancelled() else job.future.exception()
                broken = broken or isinstance(exc, BrokenProcessPool)
                self.events["requeued"] += 1
                self.store.requeue_or_fail(fit_id, f"a worker process died while it ran ({type(exc).__name__})",
                                           job.phase)
            del self.running[fit_id]
            self.workers.forget(job.future)
        if broken:
            self.restart()
        return ended

    def enforce_time_limit(self) -> int:
        """Fail and stop the jobs past the time limit; how many."""
        late = [f for f, job in self.running.items()
                if time.time() - job.started > self.time_limit_s and not job.future.done()]
        if not late:
            return 0
        for fit_id in late:
            self.events["timeouts"] += 1
            self.store.update(fit_id, "failed", 1.0, reason=f"took longer than the {self.time_limit_s:.0f} s limit")
        if self.workers.stop([self.running[f].future for f in late]):  # the others stopped with them start again
            for fit_id, job in self.running.items():
                if fit_id not in late and not job.finished_itself():
                    self.store.requeue_or_fail(fit_id, "its worker pool was replaced", job.phase, charge=False)
            self.running.clear()
        for fit_id in late:
            self.running.pop(fit_id, None)
        return len(late)

    def restart(self) -> None:
        """A fresh set of workers; every job the old ones held and did not finish is
        claimable again (a broken pool fails them all, so each is charged a try)."""
        self.events["worker_restarts"] += 1
        # the old workers stopped first (a Ray task cancelled), so no job runs twice
        if not self.workers.stop([job.future for job in self.running.values()]):
            self.workers.restart()
        for fit_id, job in list(self.running.items()):
            if not job.finished_itself():
                self.store.requeue_or_fail(fit_id, "a worker process died while it ran", job.phase)
        self.running.clear()

    def sweep(self) -> int:
        """Claimed fits of this lane's phases that no worker holds (a claim whose
        hand-over failed half-way): claimable again. The dispatcher is the only claimer,
        so such a claim is an orphan. Returns how many."""
        orphans = [(f, p) for f, p in self.store.claimed() if p in self.phases and f not in self.running]
        for fit_id, phase in orphans:
            self.store.requeue_or_fail(fit_id, "its hand-over to a worker failed", phase, charge=False)
        return len(orphans)

    def close(self) -> None:
        self.workers.close()
        for fit_id, job in list(self.running.items()):  # cut off here: claimable again at the next start
            if not job.finished_itself():
                self.store.requeue_or_fail(fit_id, "the server stopped while it ran", job.phase, charge=False)
        self.running.clear()


class Dispatcher:
    """Hands waiting phases to the lanes' workers from a thread of its own. `generation`
    counts the changes it made or saw (a job claimed, ended, timed out): a long poll reads
    a fit again only when it moved. `notify()` wakes it at once (a fit was posted)."""

    def __init__(self, store: Store, data: Path, workers: int, time_limit_s: float, retention_s: float,
                 answer_workers: int = 1, ray_address: str | None = None):
        self.store, self.data, self.workers = store, data, workers
        self.answer_workers, self.ray_address = answer_workers, ray_address
        self.time_limit_s, self.retention_s = time_limit_s, retention_s
        self.lanes: list[Lane] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, name="tryon-dispatch", daemon=True)
        self.events = {"worker_restarts": 0, "timeouts": 0, "requeued": 0, "orphans": 0, "dispatch_errors": 0}
        self.wake = threading.Event()
        self.generation = 0
        self._ray_started = False

    def notify(self) -> None:
        self.wake.set()

    def call(self, fn, *args) -> Future | None:
        """`fn(*args)` run by the answer lane's workers (a body fit: the server's own
        process stays free to answer); None when there are none or they cannot take it
        now (the caller then runs it itself)."""
        if not self.lanes:
            return None
        try:
            return self.lanes[0].workers.call(fn, *args)
        except Exception:  # noqa: BLE001 - a pool being replaced, a lost cluster
            return None

    def start(self) -> None:
        if self.workers <= 0:
            return
        kind = LocalWorkers
        if self.ray_address:
            from tryon.parallel.executors import connect_ray, ray_is_initialized

            joined_before = ray_is_initialized()
            connect_ray(self.ray_address, self.workers + self.answer_workers)
            self._ray_started = not joined_before
            kind = RayWorkers
        self.lanes = [
            Lane("answer", ("answer",), kind(self.answer_workers, 0), self.store, self.data,
                 min(self.time_limit_s, ANSWER_TIME_LIMIT_S), self.events, self.wake),
            Lane("work", ("refine", "simulate"), kind(self.workers, REFINE_NICENESS), self.store, self.data,
                 self.time_limit_s, self.events, self.wake),
        ]
        self.thread.start()

    def close(self) -> None:
        self.stop.set()
        self.wake.set()
        if self.thread.is_alive():
            self.thread.join(timeout=5.0)
        for lane in self.lanes:
            lane.close()
        if self._ray_started:
            import ray

            ray.shutdown()

    def ready(self) -> bool:
        """Whether the lanes' workers are warm (True with none)."""
        return all(lane.workers.warm() for lane in self.lanes)

    def worker_pids(self) -> dict[str, list[int]]:
        return {lane.name: lane.workers.pids() for lane in self.lanes}

    def _loop(self) -> None:
        last_prune = last_sweep = 0.0
        while not self.stop.is_set():
            self.wake.clear()
            for lane in self.lanes:
                try:
                    if lane.collect() + lane.enforce_time_limit() + lane.fill():
                        self.generation += 1
                    if time.time() - last_sweep > SWEEP_EVERY_S:
                        self.events["orphans"] += lane.sweep()
                except Exception:  # noqa: BLE001 - the loop must outlive any one job's trouble
                    self.events["dispatch_errors"] += 1
                    time.sleep(0.5)
            if time.time() - last_sweep > SWEEP_EVERY_S:
                last_sweep = time.time()
            if time.time() - last_prune > PRUNE_EVERY_S:
                self._prune()
                last_prune = time.time()
            self.wake.wait(IDLE_POLL_S)

    def _prune(self) -> None:
        try:
            fits, bodies = self.store.prune(self.retention_s)
            for fit_id in fits:
                shutil.rmtree(fit_folder(self.data, fit_id), ignore_errors=True)
            for body_id in bodies:
                body_path(self.data, body_id).unlink(missing_ok=True)
        except Exception:  # noqa: BLE001 - a busy database, a file in use: next time
            self.events["dispatch_errors"] += 1
