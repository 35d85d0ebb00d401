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
def on_numba_threads():
    """`run(fn)`: the results of fn(threads) on 1 and then 2 of numba's threads (the thread
    count restored after); skips where numba has fewer than 2 threads."""
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs 2 numba threads")

    def run(fn, counts=(1, 2)):
        before = numba.get_num_threads()
        try:
            results = []
            for threads in counts:
                numba.set_num_threads(threads)
                results.append(fn(threads))
            return results
        finally:
            numba.set_num_threads(before)

    return run


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


@pytest.fixture(scope="session")
def arm_raise_frames(tmp_path_factory):
    """A folder of 8 front views (480 x 640, taken 0.2 s apart) of the average body raising
    its arms (the built-in arm raise, its first half)."""
    import numpy as np
    from PIL import Image

    from tryon.body.anny_model import ShapeParams, body_model
    from tryon.body.motion import load_motion
    from tryon.body.pose import posed_vertices
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes

    folder = tmp_path_factory.mktemp("arm-raise")
    shape = body_model().rest_shape(ShapeParams())
    poses = load_motion("arm-raise").pose_matrices(shape)
    verts = [posed_vertices(shape, poses[k]).detach().numpy() for k in np.linspace(0, len(poses) // 2, 8).astype(int)]
    cam = Camera.fit(verts, "front", aspect=480 / 640, margin=1.25)
    for i, v in enumerate(verts):
        img = render_meshes([RenderMesh(v, np.asarray(shape.faces), color=(0.85, 0.68, 0.58))], 480, 640, cam,
                            background=(0.55, 0.6, 0.65), backend="numpy")
        Image.fromarray(img).save(folder / f"frame{i:02d}.png")
    return folder
