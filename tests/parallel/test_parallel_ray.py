"""Time-parallel runs on a local Ray (2 CPUs), one Ray session for the module: the
streaming Ray path and the failure case (a worker killed mid-segment)."""

import os

import numpy as np
import pytest

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

from tryon.parallel import ParallelOptions, simulate_time_parallel  # noqa: E402
from tryon.parallel.segment import FAULT_ENV  # noqa: E402
from tryon.sim.runner import simulate  # noqa: E402
from tryon.sim.scene import example_scene  # noqa: E402

pytestmark = [pytest.mark.ray, pytest.mark.slow]


@pytest.fixture(scope="module")
def fault_marker(tmp_path_factory):
    """The file the worker of segment 1 creates when it kills itself at step 22."""
    return tmp_path_factory.mktemp("chaos") / "killed"


@pytest.fixture(scope="module")
def ray_session(fault_marker):
    import ray

    fault = {FAULT_ENV: f"1:22:{fault_marker}"}  # in the workers only (see test_a_killed_worker_loses_no_frame)
    ray.init(num_cpus=2, object_store_memory=128 * 1024 * 1024, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": fault})
    yield ray
    ray.shutdown()


def _scene():
    return example_scene("sphere-drop", 13, duration=0.3)


@pytest.fixture(scope="module")
def serial():
    return simulate(_scene(), progress=False)


def test_a_killed_worker_loses_no_frame(ray_session, serial, fault_marker):
    """The worker of the last segment is killed (SIGKILL) at step 22 of 30, the first time
    a worker gets there (a killer from outside races a fast segment to its end): Ray
    re-runs the segment and the joined run still has every frame once."""
    opts = ParallelOptions(workers=2, partition="uniform")
    assert not fault_marker.exists(), "this test runs first in the module: no worker has met the fault yet"
    r = simulate_time_parallel(_scene(), opts, progress=False)
    assert fault_marker.exists(), "the worker of segment 1 was killed"
    assert r.summary["parallel"]["attempts"]["1"] >= 2
    assert np.allclose(r.times, serial.times)
    steps = [k for s in r.segments for k in s.own_steps]
    assert steps == sorted(set(steps)) and len(steps) == len(serial.times) - 1
    assert np.all(np.isfinite(r.positions))


def test_ray_run_streams_segments_from_worker_processes(ray_session, serial):
    seen = []
    r = simulate_time_parallel(_scene(), ParallelOptions(workers=2, partition="balanced"), progress=False,
                               on_progress=seen.append)
    assert ray_session.is_initialized()  # a Ray the caller started is left running
    assert r.positions.shape == serial.positions.shape and np.allclose(r.times, serial.times)
    first = len(r.segments[0].own_steps) + 1
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




def test_simulate_command_runs_time_parallel_with_a_larger_coarse_step(ray_session, serial, tmp_path):
    import json

    from tryon.cli import main

    out = tmp_path / "run"
    rc = main(["simulate", "--example", "sphere-drop", "--resolution", "13", "--duration", "0.3", "--parallel", "time",
               "--workers", "2", "--partition", "uniform", "--coarse-dt-ratio", "3", "--crossfade", "0.05", "--no-obj", "--out", str(out),
               "--quiet"])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    par = summary["parallel"]
    assert par["dt_ratio"] == 3 and all(c % 3 == 0 for c in par["cuts"]) and par["cuts"][-1] == 30
    assert par["crossfade"]["steps"] == 5
    frames = np.load(out / "frames.npz")
    assert frames["positions"].shape == serial.positions.shape
