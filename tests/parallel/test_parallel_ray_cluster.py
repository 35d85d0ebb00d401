"""Time-parallel runs against a Ray cluster started with `ray start` on loopback: a run
with its address uses it, and a run without an address meanwhile starts a Ray of its own
instead of joining that cluster."""

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ray, pytest.mark.slow]

SCRIPT = textwrap.dedent("""
    import json, sys, time
    from tryon.parallel import ParallelOptions, simulate_time_parallel
    from tryon.sim.scene import example_scene

    out = {}
    for name, address in (("cluster", sys.argv[1]), ("own", None)):
        opts = ParallelOptions(workers=2, partition="uniform", ray_address=address)
        tic = time.perf_counter()
        r = simulate_time_parallel(example_scene("sphere-drop", 13, duration=0.3), opts, progress=False)
        out[name] = {"s": time.perf_counter() - tic, "frames": len(r.times), "intersections": r.summary["intersections"],
                     "segments": len(r.segments), "ray": r.summary["parallel"]["ray"]}
    print("RESULT " + json.dumps(out))
""")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for(port: int, timeout: float = 90.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
            return
        except OSError:
            time.sleep(0.5)
    raise AssertionError(f"ray start did not listen on port {port} within {timeout:.0f} s")


@pytest.fixture
def cluster():
    """A Ray head on loopback with 3 CPUs (a run's own Ray has as many as its workers), as a
    user starts one; stopped with its process."""
    port = _free_port()
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled"}
    env.pop("RAY_ADDRESS", None)
    temp = tempfile.mkdtemp(prefix="rc", dir="/tmp")  # short: Ray's socket paths live under it
    ray_bin = Path(sys.executable).with_name("ray")
    head = subprocess.Popen([str(ray_bin), "start", "--head", "--block", "--node-ip-address", "127.0.0.1",
                             "--port", str(port), "--num-cpus", "3", "--include-dashboard", "false",
                             "--disable-usage-stats", "--temp-dir", temp],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for(port)
        yield f"127.0.0.1:{port}", env
    finally:
        head.terminate()
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            head.kill()
        shutil.rmtree(temp, ignore_errors=True)


def test_a_run_uses_a_cluster_started_with_ray_start_and_a_local_run_keeps_its_own(cluster):
    address, env = cluster
    r = subprocess.run([sys.executable, "-c", SCRIPT, address], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-1500:]
    result = json.loads(r.stdout.split("RESULT ", 1)[1])
    for name in ("cluster", "own"):
        assert result[name]["frames"] == 9 and result[name]["segments"] == 2, result
        assert result[name]["intersections"] == 0, result
    cluster, own = result["cluster"]["ray"], result["own"]["ray"]
    assert cluster["address"].endswith(address.split(":")[1]) and cluster["cpus"] == 3 and not cluster["own"], result
    assert own["address"] != cluster["address"] and own["cpus"] == 2 and own["own"], result
