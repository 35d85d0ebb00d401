import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import torch

os.environ.setdefault("TQDM_DISABLE", "1")
torch.set_num_threads(1)
if os.environ.get("PYTEST_XDIST_WORKER"):
    # Several test processes share the cores (`make test` runs one per core): each runs the
    # compiled kernels on one thread (the tests of thread-count invariance ask for two
    # themselves), and OpenMP threads, here and in the processes tests start, sleep instead
    # of spinning while they wait, so that no process burns a core another one needs.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import numba

    numba.set_num_threads(1)


@pytest.fixture
def tmp_out(tmp_path):
    return tmp_path / "out"


@pytest.fixture(scope="session")
def size_m_man():
    """The men's size-M fit model (Anny fitted to the size chart) and its drafting
    measurements, fitted once for every test that drafts on it."""
    from tryon.body.fit import Measurements, fit_body
    from tryon.body.measure import drafting_measurements
    from tryon.garment.sizes import size_measurements

    m = size_measurements("M", "male")
    fit = fit_body(Measurements(height_cm=m["height_cm"], gender="male", chest_cm=m["chest_cm"], waist_cm=m["waist_cm"],
                                hip_cm=m["hip_cm"]), prior=False)  # as tryon drape fits a size's fit model
    return fit.shape, drafting_measurements(fit.shape)


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
def ray_cluster():
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
