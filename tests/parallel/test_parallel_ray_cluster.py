"""Time-parallel runs against a Ray cluster started with `ray start` on loopback: a run
with its address uses it, and a run without an address meanwhile starts a Ray of its own
instead of joining that cluster."""

import json
import subprocess
import sys
import textwrap

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


def test_a_run_uses_a_cluster_started_with_ray_start_and_a_local_run_keeps_its_own(ray_cluster):
    address, env = ray_cluster
    r = subprocess.run([sys.executable, "-c", SCRIPT, address], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-1500:]
    result = json.loads(r.stdout.split("RESULT ", 1)[1])
    for name in ("cluster", "own"):
        assert result[name]["frames"] == 9 and result[name]["segments"] == 2, result
        assert result[name]["intersections"] == 0, result
    cluster, own = result["cluster"]["ray"], result["own"]["ray"]
    assert cluster["address"].endswith(address.split(":")[1]) and cluster["cpus"] == 3 and not cluster["own"], result
    assert own["address"] != cluster["address"] and own["cpus"] == 2 and own["own"], result
