"""`tryon serve --ray-address`: the jobs run as Ray tasks on a cluster started with `ray
start` on loopback, with the same answers as the service's own worker processes."""

import pytest

pytestmark = [pytest.mark.ray, pytest.mark.anny, pytest.mark.slow]


def test_fits_run_on_a_ray_cluster_with_the_same_answers(ray_cluster, tmp_path):
    from tryon.bench.serve import Client, Server
    from tryon.body.amortised import quick_fit
    from tryon.body.fit import Measurements
    from tryon.sizing.quick import first_answer

    address, env = ray_cluster
    server = Server(tmp_path / "data", workers=1, answer_workers=1, ray_address=address, env=env)
    server.start()
    try:
        client = Client(server.port)
        person = {"height_cm": 176.0, "weight_kg": 74.0, "gender": "male"}
        body = client.call("POST", "/v1/bodies", person)[1]
        fit = client.call("POST", "/v1/fits", {"body_id": body["body_id"], "garment": "tshirt"})[1]
        status, views = "queued", {}
        for _ in range(60):
            view = client.call("GET", f"/v1/fits/{fit['fit_id']}?wait=20&after={status}")[1]
            status = view["status"]
            views[status] = view
            if status in ("refined", "failed"):
                break
        assert status == "refined", view
        assert server.worker_pids() == {"answer": [], "work": []}  # no worker process of the server's own
    finally:
        server.stop()
    local = first_answer(quick_fit(Measurements(**person)), "male", "tshirt")
    predicted = views["predicted"]
    assert predicted["recommended"] == local.recommended
    for entry, mine in zip(predicted["sizes"], local.sizes):
        assert entry["size"] == mine.size and entry["ease_cm"] == pytest.approx(mine.judged["torso_ease_cm"], abs=1e-3)
