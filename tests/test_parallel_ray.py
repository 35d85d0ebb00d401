"""Time-parallel runs on a local Ray (2 CPUs), one Ray session for the module: the
streaming Ray path and the failure case (a worker killed mid-segment)."""

import os
import signal

import numpy as np
import pytest

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

from tryon.parallel import ParallelOptions, simulate_time_parallel  # noqa: E402
from tryon.sim.runner import simulate  # noqa: E402
from tryon.sim.scene import example_scene  # noqa: E402


@pytest.fixture(scope="module")
def ray_session():
    import ray

    ray.init(num_cpus=2, object_store_memory=128 * 1024 * 1024, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def _scene():
    return example_scene("sphere-drop", 13, duration=0.3)


@pytest.fixture(scope="module")
def serial():
    return simulate(_scene(), progress=False)


def test_ray_run_streams_segments_from_worker_processes(ray_session, serial):
    seen = []
    r = simulate_time_parallel(_scene(), ParallelOptions(workers=2, partition="balanced"), progress=False,
                               on_progress=seen.append)
    assert ray_session.is_initialized()  # a Ray the caller started is left running
    assert r.positions.shape == serial.positions.shape and np.allclose(r.times, serial.times)
    first = len(r.segments[0].frame_steps) + 1
    assert np.allclose(r.positions[:first], serial.positions[:first], atol=1e-7)
    assert {p.pid for p in seen} - {os.getpid()}, "segments ran in Ray worker processes"
    assert r.summary["parallel"]["mode"] == "ray" and len(r.segments) == 2
    assert r.summary["intersections"] == 0


def test_adaptive_partition_on_ray_decides_cuts_online(ray_session, serial):
    """Cuts are decided while segments run; with a measured K near 1 the balanced rule
    may give the whole run to one segment, so only the coverage is fixed."""
    r = simulate_time_parallel(_scene(), ParallelOptions(workers=2, partition="adaptive"), progress=False)
    par = r.summary["parallel"]
    assert par["cuts"][0] == 0 and par["cuts"][-1] == 30 and len(r.segments) == len(par["cuts"]) - 1
    assert [h["cut"] for h in par["adaptive_history"]][: len(par["cuts"]) - 2] == par["cuts"][1:-1]
    assert np.allclose(r.times, serial.times)


def test_a_killed_worker_loses_no_frame(ray_session, serial):
    """Kill the worker of the last segment a few steps in: Ray re-runs the segment and
    the joined run still has every frame once."""
    killed = []

    def kill_once(p):
        if not killed and p.index == 1 and p.phase == "step" and p.step >= 22 and p.pid != os.getpid():
            os.kill(p.pid, signal.SIGKILL)
            killed.append(p.pid)

    opts = ParallelOptions(workers=2, partition="uniform")
    r = simulate_time_parallel(_scene(), opts, progress=False, on_progress=kill_once)
    assert killed
    assert r.summary["parallel"]["attempts"]["1"] >= 2
    assert np.allclose(r.times, serial.times)
    steps = [k for s in r.segments for k in s.frame_steps]
    assert steps == sorted(set(steps)) and len(steps) == len(serial.times) - 1
    assert np.all(np.isfinite(r.positions))
