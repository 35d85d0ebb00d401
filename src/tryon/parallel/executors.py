"""Where fine segments run: Ray tasks (a local Ray started with `workers` CPUs, or a
cluster joined with `address`) or, for tests and debugging, this process.

Both executors take the same `SegmentSpec`s and hand back `SegmentResult`s as segments
finish (streaming); both report per-step `Progress`, from which the driver measures the
fine cost per step (for the adaptive partition) and its progress bar. A Ray worker that
dies mid-segment (killed, out of memory, node lost) has its task re-run by Ray; if Ray
gives up, the executor submits the segment again, up to `max_attempts` times in all.
"""

from __future__ import annotations

import os
import secrets
import socket
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from tryon.errors import SimulationError, TryonError
from tryon.parallel.hierarchy import Hierarchy
from tryon.parallel.segment import Progress, SegmentResult, SegmentSpec, segment_run

RAY_ENV = {"RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled"}


@dataclass
class ProgressTable:
    """Latest progress of every segment plus the fine step costs measured so far."""

    latest: dict[int, Progress] = field(default_factory=dict)
    attempts: dict[int, int] = field(default_factory=dict)
    fine_seconds: float = 0.0
    fine_steps: int = 0
    listener: Callable[[Progress], None] | None = None

    def add(self, p: Progress) -> None:
        if p.phase == "start":  # restarts count too (the summary also lists them in restarted_segments)
            self.attempts[p.index] = self.attempts.get(p.index, 0) + 1
        else:
            self.fine_seconds += p.seconds
            self.fine_steps += 1
        self.latest[p.index] = p
        if self.listener is not None:
            self.listener(p)

    def fine_cost(self) -> float | None:
        return self.fine_seconds / self.fine_steps if self.fine_steps else None


class LocalExecutor:
    """Runs segments in this process, interleaved one fine step at a time with the
    driver's coarse steps (cooperative generators: same results as the Ray path, no
    concurrency)."""

    mode = "local"

    def __init__(self, hier: Hierarchy):
        self.hier = hier
        self.table = ProgressTable()
        self._running: dict[int, list] = {}  # index -> [generator, last progress, end]

    def submit(self, spec: SegmentSpec) -> None:
        gen = segment_run(self.hier, spec)
        first = next(gen)
        self.table.add(first)
        self._running[spec.index] = [gen, first, spec.end]

    def set_end(self, index: int, end: int) -> None:
        if index in self._running:
            self._running[index][2] = end

    def poll(self, limit: int, timeout: float = 0.0) -> list[SegmentResult]:
        """Advance every running segment by one fine step (an open-ended one only while it
        is behind the coarse run at `limit`); return the segments that finished."""
        done = []
        for index, entry in list(self._running.items()):
            gen, last, end = entry
            if end is None and last.step >= limit:
                continue
            try:
                entry[1] = gen.send(end)
                self.table.add(entry[1])
            except StopIteration as stop:
                done.append(stop.value)
                del self._running[index]
        return done

    def close(self) -> None:
        self._running.clear()


# ---------------------------------------------------------------------------- Ray

_AUTH_KEYS = ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN")
_USER_AUTH: dict[str, str | None] | None = None  # the user's own settings, before a local Ray changed them


def ray_environment() -> None:
    """Environment for joining a Ray cluster: no usage stats; token authentication only
    where the user's environment asks for it (as the cluster was started)."""
    if _USER_AUTH is not None:  # undo what a local Ray of an earlier run set
        for key, value in _USER_AUTH.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        _reload_ray_settings()
    for key, value in RAY_ENV.items():
        os.environ.setdefault(key, value)


def local_ray_environment() -> None:
    """Environment for a Ray of this run's own. Ray's servers listen on every interface,
    so the local Ray requires a fresh random token from every client: only this process
    and the workers it starts (which inherit the environment) can submit work to it."""
    global _USER_AUTH
    if _USER_AUTH is None:
        _USER_AUTH = {key: os.environ.get(key) for key in _AUTH_KEYS}
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    os.environ["RAY_AUTH_MODE"] = "token"
    os.environ["RAY_AUTH_TOKEN"] = secrets.token_hex(32)
    _reload_ray_settings()


def _reload_ray_settings() -> None:
    if "ray" in sys.modules:  # Ray read its settings when it was imported: make it read them again
        from ray._raylet import AuthenticationTokenLoader, Config

        Config.initialize("")
        AuthenticationTokenLoader.instance().reset_cache()


def check_address(address: str, timeout: float = 3.0) -> None:
    """Fail fast (a TryonError) when nothing listens at a Ray address `host:port`
    (optionally `ray://host:port`); 'auto' and 'local' are left to Ray."""
    if address in ("auto", "local"):
        return
    host, _, port = address.split("://")[-1].rpartition(":")
    if not host or not port.isdigit():
        raise TryonError(f"--ray-address {address!r} is not host:port (e.g. 192.168.1.10:6379 or ray://head:10001)")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise TryonError(f"no Ray cluster answers at {address!r} ({exc.strerror or exc}); start one with `ray start "
                         "--head` there or run without --ray-address for a local Ray") from exc


def ray_is_initialized() -> bool:
    """Whether this process is connected to a Ray (without importing Ray for nothing)."""
    return "ray" in sys.modules and sys.modules["ray"].is_initialized()


def connect_ray(address: str | None, workers: int, object_store_mb: int = 256) -> bool:
    """Join the Ray at `address`, reuse an initialised one, or start a local Ray with
    `workers` CPUs and a small object store. True when this call started it."""
    if ray_is_initialized():
        return False
    if address == "local":
        address = None
    if address:
        ray_environment()
    else:
        local_ray_environment()
    import ray

    if address:
        check_address(address)
    try:
        if address:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        else:
            # address="local": always a Ray of this run's own, even while another
            # cluster runs on this machine (token-protected, see local_ray_environment)
            ray.init(address="local", num_cpus=workers,
                     object_store_memory=object_store_mb * 1024 * 1024, include_dashboard=False, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = f"the Ray cluster at {address!r}" if address else "a local Ray"
        raise TryonError(f"could not start or join {where} ({exc}); check --ray-address or run without it") from exc
    return True


class _Board:
    """Ray actor the segments report to and read their (late-decided) end from."""

    def __init__(self) -> None:
        self.ends: dict[int, int] = {}
        self.limit = 0
        self.reports: list[Progress] = []
        self.warm: set[int] = set()

    def arrive(self, pid: int) -> int:
        """A warmed-up worker process checks in; returns how many distinct ones have."""
        self.warm.add(pid)
        return len(self.warm)

    def set_end(self, index: int, end: int) -> None:
        self.ends[index] = end

    def set_limit(self, limit: int) -> None:
        self.limit = max(self.limit, limit)

    def end_of(self, index: int) -> tuple[int | None, int]:
        return self.ends.get(index), self.limit

    def report(self, p: Progress) -> None:
        self.reports.append(p)

    def drain(self) -> list[Progress]:
        out, self.reports = self.reports, []
        return out


@contextmanager
def worker_threads() -> Iterator[None]:
    """torch and numba on one thread each inside the block, as in a worker (the coarse run
    beside the workers; a serial baseline that compares with them), the previous counts
    restored after."""
    import numba
    import torch

    threads, kernels = torch.get_num_threads(), numba.get_num_threads()
    one_thread_per_worker()
    try:
        yield
    finally:
        torch.set_num_threads(threads)
        numba.set_num_threads(kernels)


def one_thread_per_worker() -> None:
    """A Ray worker gets one core: torch and numba (the solver's and collision queries'
    threads) on one thread each, or the workers of a machine fight over its cores."""
    import numba
    import torch

    torch.set_num_threads(1)
    numba.set_num_threads(1)


def _segment_task(hier: Hierarchy, spec: SegmentSpec, board) -> SegmentResult:
    """Body of the Ray task: drive `segment_run`, reporting progress, polling for the end."""
    import ray

    one_thread_per_worker()
    gen = segment_run(hier, spec)
    progress = next(gen)
    end = spec.end
    while True:
        board.report.remote(progress)
        if end is None:
            end = _wait_for_end(ray, board, spec.index, progress.step)
        try:
            progress = gen.send(end)
        except StopIteration as stop:
            return stop.value


def _wait_for_end(ray, board, index: int, step: int) -> int | None:
    """The segment's end once decided; None while it may still step (behind the coarse run)."""
    while True:
        end, limit = ray.get(board.end_of.remote(index))
        if end is not None or step < limit:
            return end
        time.sleep(0.02)


class RayExecutor:
    """Fine segments as Ray tasks (one CPU each); results stream back as they finish."""

    mode = "ray"

    def __init__(self, hier: Hierarchy, workers: int, address: str | None = None, max_attempts: int = 3,
                 object_store_mb: int = 256, task_retries: int = 2):
        import ray

        self._ray = ray
        self.started_ray = connect_ray(address, workers, object_store_mb)
        self.table = ProgressTable()
        self.max_attempts = max_attempts
        self.resubmitted = 0
        self._hier_ref = ray.put(hier)
        # which Ray the run uses: its own, or the cluster it joined (the summary says so)
        self.cluster = {"address": ray.get_runtime_context().gcs_address, "own": self.started_ray and address in (None, "local"),
                        "cpus": float(ray.cluster_resources().get("CPU", 0.0))}
        self._board = ray.remote(num_cpus=0)(_Board).remote()
        self._task = ray.remote(num_cpus=1, max_retries=task_retries)(_segment_task)
        self._pending: dict = {}  # ObjectRef -> (spec, submissions)
        self._ends: dict[int, int] = {}
        self._limit = -1

    def warm_up(self, workers: int) -> float:
        """Start the worker processes and load the simulator there (imports, compiled
        kernels, one fine step); returns the seconds it took (reported apart from the run).
        Each warm-up task waits for the others, so that they run in `workers` distinct
        processes (a fast one would otherwise take the next task, and a segment would
        start a cold process inside the timed run)."""
        tic = time.perf_counter()
        warm = self._ray.remote(num_cpus=1)(_warm_worker)
        together = max(1, min(workers, int(self._ray.cluster_resources().get("CPU", workers))))
        self._ray.get([warm.remote(self._hier_ref, self._board, together) for _ in range(workers)])
        return time.perf_counter() - tic

    def submit(self, spec: SegmentSpec, submissions: int = 1) -> None:
        ref = self._task.remote(self._hier_ref, spec, self._board)
        self._pending[ref] = (spec, submissions)

    def set_end(self, index: int, end: int) -> None:
        self._ends[index] = end
        self._board.set_end.remote(index, end)

    def poll(self, limit: int, timeout: float = 0.0) -> list[SegmentResult]:
        ray = self._ray
        if limit != self._limit:
            self._board.set_limit.remote(limit)
            self._limit = limit
        done = []
        if self._pending:
            ready, _ = ray.wait(list(self._pending), num_returns=len(self._pending), timeout=timeout)
            for ref in ready:
                done.extend(self._collect(ref))
        for p in ray.get(self._board.drain.remote()):
            self.table.add(p)
        return done

    def _collect(self, ref) -> list[SegmentResult]:
        ray = self._ray
        spec, submissions = self._pending.pop(ref)
        try:
            return [ray.get(ref)]
        except ray.exceptions.RayTaskError as exc:
            cause = getattr(exc, "cause", None)
            if isinstance(cause, TryonError):
                raise cause
            raise SimulationError(f"fine segment {spec.index} failed: {exc}") from exc
        except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError, ray.exceptions.ObjectLostError,
                ray.exceptions.RaySystemError) as exc:
            if submissions >= self.max_attempts:
                raise SimulationError(f"fine segment {spec.index} was lost {submissions} times ({type(exc).__name__}); "
                                      "check the Ray workers' memory and logs") from exc
            if spec.end is None and spec.index in self._ends:
                spec.end = self._ends[spec.index]
            self.resubmitted += 1
            self.submit(spec, submissions + 1)
            return []

    def close(self) -> None:
        ray = self._ray
        for ref in list(self._pending):
            ray.cancel(ref, force=True)
        self._pending.clear()
        try:
            ray.kill(self._board)
        except Exception:  # the actor may already be gone with its node
            pass
        if self.started_ray:
            ray.shutdown()


def _warm_worker(hier: Hierarchy, board=None, workers: int = 1, wait_s: float = 30.0) -> int:
    """Warm-up task: load the simulator's and the recovery's kernels in a worker (one fine
    step, one obstacle clearance), then check in at `board` and wait (up to `wait_s`)
    until `workers` distinct processes have; returns its pid."""
    import ray

    from tryon.sim.integrator import ImplicitEulerSolver
    from tryon.sim.loop import run

    from tryon.parallel.recovery import clear_of_obstacles

    one_thread_per_worker()
    fine = hier.fine
    state = fine.model.initial_state()
    run(ImplicitEulerSolver(fine.model, fine.options), state, fine.dt, until=1)
    x = state.x.numpy()
    clear_of_obstacles(hier, hier.track(x, hier.restrict(x)), 0.0)  # recovery's kernels and factorisation
    if board is not None:
        deadline = time.monotonic() + wait_s
        while ray.get(board.arrive.remote(os.getpid())) < workers and time.monotonic() < deadline:
            time.sleep(0.02)
    return os.getpid()
