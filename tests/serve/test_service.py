"""The try-on service through its HTTP API (FastAPI's test client, a temporary --data)."""

import time

import pytest
from fastapi.testclient import TestClient

from tryon.serve.app import Settings, create_app
from tryon.serve.store import Store

BODY = {"height_cm": 172, "weight_kg": 70, "gender": "male"}


def _client(tmp_path, **kw) -> TestClient:
    return TestClient(create_app(Settings(tmp_path / "data", **kw)))


@pytest.mark.parametrize("payload, field", [
    ({"weight_kg": 70, "gender": "male"}, "height_cm"),
    ({**BODY, "height_cm": "tall"}, "height_cm"),
    ({**BODY, "height_cm": 500}, "height_cm"),
    ({**BODY, "gender": "robot"}, "gender"),
    ({**BODY, "chest_cm": -3}, "chest_cm"),
    ({**BODY, "shoe": 44}, "shoe"),
])
def test_a_bad_body_is_refused_naming_the_field(tmp_path, payload, field):
    with _client(tmp_path, workers=0) as client:
        r = client.post("/v1/bodies", json=payload)
    assert r.status_code == 422 and field in r.json()["detail"]


def test_bad_fits_and_ids_answer_4xx(tmp_path):
    with _client(tmp_path, workers=0) as client:
        assert client.post("/v1/fits", json={"body_id": "body_0123456789abcdef"}).status_code == 404
        r = client.post("/v1/fits", json={"body_id": "body_0123456789abcdef", "garment": "cape"})
        assert r.status_code == 422 and "garment" in r.json()["detail"]
        r = client.post("/v1/fits", json={"body_id": "body_0123456789abcdef", "fabric": "chainmail"})
        assert r.status_code == 422 and "chainmail" in r.json()["detail"]
        r = client.post("/v1/fits", json={"body_id": "body_0123456789abcdef", "sizes": ["M", "M"]})
        assert r.status_code == 422 and "once" in r.json()["detail"]
        assert client.get("/v1/fits/fit_0123456789abcdef").status_code == 404
        assert client.get("/v1/fits/../../etc/passwd").status_code == 404
        for name in ("..%2F..%2Ftryon.sqlite", "tryon.sqlite", "x.glb%00.png"):
            assert client.get(f"/v1/files/fit_0123456789abcdef/{name}").status_code == 404


def test_a_full_queue_answers_429_and_a_repeated_post_the_same(tmp_path):
    store = Store(tmp_path / "data" / "tryon.sqlite")
    body_id = store.add_body(BODY, {"measurements": {}})
    with _client(tmp_path, workers=0, max_queue=2) as client:  # no workers: fits stay queued
        first = client.post("/v1/fits", json={"body_id": body_id}, headers={"Idempotency-Key": "k1"})
        again = client.post("/v1/fits", json={"body_id": body_id}, headers={"Idempotency-Key": "k1"})
        assert first.status_code == again.status_code == 202 and first.json()["fit_id"] == again.json()["fit_id"]
        assert client.post("/v1/fits", json={"body_id": body_id}).status_code == 202
        full = client.post("/v1/fits", json={"body_id": body_id})
        assert full.status_code == 429 and full.headers["Retry-After"] == "5"
        assert client.get(f"/v1/fits/{first.json()['fit_id']}").json()["status"] == "queued"


def test_a_job_cut_off_by_a_stop_is_queued_again_then_failed_with_its_reason(tmp_path):
    store = Store(tmp_path / "data" / "tryon.sqlite")
    body_id = store.add_body(BODY, {"measurements": {}})
    fit_id = store.add_fit(body_id, {"garment": "tshirt", "fabric": "gray-interlock", "sizes": None})
    for expected in ("queued", "failed"):
        assert store.claim_next() == (fit_id, "answer")
        with _client(tmp_path, workers=0) as client:  # a start finds it running
            view = client.get(f"/v1/fits/{fit_id}").json()
        assert view["status"] == expected
    assert "stopped" in view["reason"]


def test_a_token_guards_every_route(tmp_path):
    with _client(tmp_path, workers=0, token="s" * 20) as client:
        assert client.get("/health").status_code == 401
        assert client.get("/health", headers={"Authorization": "Bearer " + "s" * 20}).status_code == 200


@pytest.mark.anny
@pytest.mark.slow
def test_a_shopper_gets_a_body_then_a_predicted_then_a_refined_tshirt_size(tmp_path):
    with _client(tmp_path, workers=1) as client:
        body = client.post("/v1/bodies", json=BODY)
        assert body.status_code == 200, body.text
        b = body.json()
        assert abs(b["measurements"]["height_cm"] - 172) < 1.0 and abs(b["measurements"]["weight_kg"] - 70) < 1.5
        fit = client.post("/v1/fits", json={"body_id": b["body_id"], "garment": "tshirt", "sizes": ["M", "L"]})
        fit_id = fit.json()["fit_id"]
        seen, t0 = [], time.time()
        while time.time() - t0 < 240:
            view = client.get(f"/v1/fits/{fit_id}").json()
            if not seen or seen[-1] != view["status"]:
                seen.append(view["status"])
            if view["status"] in ("refined", "failed"):
                break
            time.sleep(0.2)
        assert view["status"] == "refined", view
        assert "predicted" in seen
        assert view["recommended"] in ("M", "L") and view["reasons"]
        refined = [s for s in view["sizes"] if s["judged_on"] == "refined drape"]
        assert view["recommended"] in [s["size"] for s in refined]
        for s in view["sizes"]:
            assert s["ease_cm"] is not None and client.get(s["scene_url"]).status_code == 200
            assert (s["not_refined"] is None) == (s in refined)
        for s in refined:
            png = client.get(s["fit_map_url"])
            assert png.status_code == 200 and png.content[:4] == b"\x89PNG"
            assert client.get(s["glb_url"]).content[:4] == b"glTF"


def test_photo_uploads_are_bounded_in_number_type_and_size(tmp_path):
    with _client(tmp_path, workers=0) as client:
        form = {"height_cm": "175", "gender": "male"}
        r = client.post("/v1/bodies/photos", data=form, files=[("photos", ("a.txt", b"hello", "text/plain"))])
        assert r.status_code == 415 and "JPEG" in r.json()["detail"]
        big = b"\xff\xd8" + b"0" * (10 * 1024 * 1024 + 10)
        r = client.post("/v1/bodies/photos", data=form, files=[("photos", ("a.jpg", big, "image/jpeg"))])
        assert r.status_code == 413
        r = client.post("/v1/bodies/photos", data=form, files=[("photos", ("a.jpg", b"not a jpeg", "image/jpeg"))])
        assert r.status_code == 422 and r.json()["detail"].startswith("photo 1 (a.jpg)"), r.json()
        assert str(tmp_path) not in r.json()["detail"]
        five = [("photos", (f"{i}.png", b"x", "image/png")) for i in range(5)]
        assert client.post("/v1/bodies/photos", data=form, files=five).status_code == 422
        r = client.post("/v1/bodies/photos", data={"gender": "male"}, files=five[:1])
        assert r.status_code == 422 and "height_cm" in r.json()["detail"]
        assert not any((tmp_path / "data" / "uploads").glob("*/*"))  # nothing kept


@pytest.mark.anny
@pytest.mark.slow
def test_a_body_from_two_photos_is_read_and_kept(tmp_path):
    import io

    from PIL import Image

    from tryon.body.fit import Measurements, fit_body
    from tryon.dataset.photos import photograph

    truth = fit_body(Measurements(height_cm=168, weight_kg=70, gender="female"))
    files = []
    for view, img in zip(("front", "left"), photograph(truth.shape, ("front", "left"), seed=3)):
        buf = io.BytesIO()
        Image.fromarray(img).save(buf, format="PNG")
        files.append(("photos", (f"{view}.png", buf.getvalue(), "image/png")))
    with _client(tmp_path, workers=0) as client:
        r = client.post("/v1/bodies/photos", data={"height_cm": "168", "gender": "female", "weight_kg": "70"},
                        files=files)
        assert r.status_code == 200, r.text
        m = r.json()["measurements"]
        assert abs(m["hip_cm"] - truth.achieved["hip_cm"]) < 0.06 * truth.achieved["hip_cm"]
        assert m["hip_cm_sd"] > 0 and r.json()["source"] == "2 photo(s)"
    stored = Store(tmp_path / "data" / "tryon.sqlite").body(r.json()["body_id"])
    assert stored[0]["hip_cm"] > 0 and stored[0]["height_cm"] == 168
    assert not any((tmp_path / "data" / "uploads").glob("*/*"))


def test_serve_refuses_to_listen_off_loopback_without_a_token(tmp_path, capsys):
    from tryon.cli import main

    assert main(["serve", "--host", "0.0.0.0", "--data", str(tmp_path / "d")]) == 2
    assert "--token-file" in capsys.readouterr().err
    (tmp_path / "tok").write_text("short\n")
    assert main(["serve", "--host", "0.0.0.0", "--token-file", str(tmp_path / "tok"), "--data", str(tmp_path / "d")]) == 2
    assert "16 characters" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("raw", [b"{not json", b"[1, 2]", b'{"height_cm": NaN, "weight_kg": 70, "gender": "male"}',
                                 b'{"height_cm": 1e999, "weight_kg": 70, "gender": "male"}', b"", b"null"])
def test_malformed_bodies_answer_422_never_500(tmp_path, raw):
    with _client(tmp_path, workers=0) as client:
        r = client.post("/v1/bodies", content=raw, headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
