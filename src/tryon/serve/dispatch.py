"""The dispatcher: a thread in the server that hands queued fits to a pool of worker
processes, and keeps every job accounted for when a worker dies or a job runs too long.

A worker that dies (killed, out of memory) breaks its pool: every job the pool held goes
back to the queue (`Store.requeue_or_fail`) and a fresh pool starts. A job past the time
limit is failed with that reason and its pool is replaced, which stops it.
"""

from __future__ import annotations

import multiprocessing
import shutil
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from tryon.serve.jobs import fit_folder, run_fit
from tryon.serve.store import Store

POLL_S = 0.05
PRUNE_EVERY_S = 60.0


def _warm_up() -> None:
    """Run in each new worker: import what a fit needs before the first job arrives."""
    import tryon.body.amortised  # noqa: F401
    import tryon.learn.size  # noqa: F401


class Dispatcher:
    def __init__(self, store: Store, data: Path, workers: int, time_limit_s: float, retention_s: float):
        self.store, self.data, self.workers = store, data, workers
        self.time_limit_s, self.retention_s = time_limit_s, retention_s
        self.running: dict[str, tuple[Future, float]] = {}
        self.pool: ProcessPoolExecutor | None = None
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, name="tryon-dispatch", daemon=True)
        self.events = {"worker_restarts": 0, "timeouts": 0, "requeued": 0}

    def start(self) -> None:
        if self.workers > 0:
            self.pool = self._new_pool()
            self.thread.start()

    def close(self) -> None:
        self.stop.set()
        if self.thread.is_alive():
            self.thread.join(timeout=5.0)
        if self.pool is not None:
            self._kill_pool(self.pool)
        # the jobs cut off here go back to the queue for the next start
        for fit_id in list(self.running):
            self.store.requeue_or_fail(fit_id, "the server stopped while it ran")
        self.running.clear()

    def worker_pids(self) -> list[int]:
        return [p.pid for p in (getattr(self.pool, "_processes", None) or {}).values()]

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=_warm_up)

    @staticmethod
    def _kill_pool(pool: ProcessPoolExecutor) -> None:
        for p in list((getattr(pool, "_processes", None) or {}).values()):
            p.kill()
        pool.shutdown(wait=False, cancel_futures=True)

    def _loop(self) -> None:
        last_prune = 0.0
        while not self.stop.is_set():
            try:
                self._collect()
                self._enforce_time_limit()
                self._fill()
                if time.time() - last_prune > PRUNE_EVERY_S:
                    self._prune()
                    last_prune = time.time()
            except Exception:  # noqa: BLE001 - the loop must outlive any one job's trouble
                time.sleep(0.5)
            self.stop.wait(POLL_S)

    def _fill(self) -> None:
        while len(self.running) < self.workers:
            fit_id = self.store.claim_next()
            if fit_id is None:
                return
            try:
                fut = self.pool.submit(run_fit, str(self.store.path), str(self.data), fit_id)
            except (BrokenProcessPool, RuntimeError):
                self.store.requeue_or_fail(fit_id, "a worker process died")
                self._restart_pool()
                return
            self.running[fit_id] = (fut, time.time())

    def _collect(self) -> None:
        broken = False
        for fit_id, (fut, _) in list(self.running.items()):
            if not fut.done():
                continue
            del self.running[fit_id]
            exc = fut.exception()
            if isinstance(exc, BrokenProcessPool):
                broken = True
                self.events["requeued"] += 1
                self.store.requeue_or_fail(fit_id, "a worker process died while it ran")
            elif exc is not None:
                self.store.update(fit_id, "failed", 1.0, reason=f"internal error: {type(exc).__name__}: {exc}"[:500])
        if broken:
            self._restart_pool()

    def _enforce_time_limit(self) -> None:
        late = [f for f, (_, t0) in self.running.items() if time.time() - t0 > self.time_limit_s]
        if not late:
            return
        for fit_id in late:
            self.events["timeouts"] += 1
            self.store.update(fit_id, "failed", 1.0, reason=f"took longer than the {self.time_limit_s:.0f} s limit")
            del self.running[fit_id]
        for fit_id in list(self.running):  # the others in the replaced pool start again
            self.store.requeue_or_fail(fit_id, "its worker pool was replaced")
            del self.running[fit_id]
        self._restart_pool()

    def _restart_pool(self) -> None:
        self.events["worker_restarts"] += 1
        for fit_id in list(self.running):
            fut, _ = self.running[fit_id]
            if not fut.done():
                self.store.requeue_or_fail(fit_id, "a worker process died while it ran")
            del self.running[fit_id]
        self._kill_pool(self.pool)
        self.pool = self._new_pool()

    def _prune(self) -> None:
        for fit_id in self.store.prune(self.retention_s):
            shutil.rmtree(fit_folder(self.data, fit_id), ignore_errors=True)
