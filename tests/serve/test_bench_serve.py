"""`tryon bench serve` in small: a real server on loopback, one shopper, a probe of bad
requests, and a worker killed mid-run without a job lost."""

import json

import pytest

pytestmark = [pytest.mark.anny, pytest.mark.slow]


def test_the_load_bench_counts_no_lost_job_when_a_worker_is_killed(tmp_path):
    from tryon.bench.serve import run_serve_bench

    out = tmp_path / "serve.json"
    run_serve_bench(str(out), shoppers=1, duration_s=8, fault_duration_s=12, workers=1, faults=("worker_killed",))
    result = json.loads(out.read_text())
    assert result["probe"]["not_4xx"] == [] and result["probe"]["bad_requests"] >= 20
    plain, killed = result["runs"]
    assert plain["fault"] == "none" and killed["fault"] == "worker_killed" and len(killed["killed_pids"]) == 2
    for run in (plain, killed):
        assert run["fits_posted"] >= 1 and run["lost_jobs"] == 0, run
        assert run["errors"] == 0, run["error_examples"]
        assert run["first_answer_p50_s"] is not None and run["refined_p95_s"] >= run["first_answer_p95_s"]
