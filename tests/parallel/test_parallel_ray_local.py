"""The local Ray a time-parallel run starts is its own and takes work only from clients
that hold its random token (Ray's servers listen on every interface)."""

import subprocess
import sys
import textwrap

import pytest

pytestmark = [pytest.mark.ray, pytest.mark.slow]

SCRIPT = textwrap.dedent("""
    import os, subprocess, sys
    os.environ["RAY_AUTH_MODE"] = "disabled"   # what a user's shell might say
    from tryon.parallel.executors import connect_ray
    import ray
    assert connect_ray(None, 1)
    assert ray.get(ray.remote(lambda: 41).remote()) + 1 == 42
    address = ray.get_runtime_context().gcs_address
    env = {k: v for k, v in os.environ.items() if k != "RAY_AUTH_TOKEN"}
    env["RAY_AUTH_MODE"] = "disabled"
    intruder = "import ray; ray.init(address=%r); print('JOINED')" % address
    r = subprocess.run([sys.executable, "-c", intruder], env=env, capture_output=True, text=True, timeout=120)
    print("INTRUDER", r.returncode, "JOINED" in r.stdout)
    ray.shutdown()
""")


def test_local_ray_refuses_clients_without_its_token():
    r = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-800:]
    assert "INTRUDER 1 False" in r.stdout, r.stdout[-500:]
