"""`tryon bench body` on two test people of the shipped photo dataset: every method's
record, with the keys the issue names, and the photos beating nobody's mean body."""

import json

import pytest


@pytest.mark.anny
def test_bench_body_writes_a_record_per_views_and_method(tmp_path):
    from tryon.cli import main

    out = tmp_path / "body.json"
    assert main(["bench", "body", "--people", "2", "--json", str(out)]) == 0
    records = json.loads(out.read_text())
    methods = {(r["views"], r["method"]) for r in records}
    assert methods == {(v, m) for v in (1, 2, 4) for m in ("photos", "photos-no-weight", "height-weight", "mean")}
    for r in records:
        assert {"views", "clothing", "method", "measurement_error_pct", "per_measurement_pct",
                "vertex_error_cm"} <= set(r)
        assert r["clothing"] == "tight" and r["people"] == 2
    photos = [r for r in records if r["method"] == "photos"]
    assert all("inference_ms" in r and r["inference_ms"] > 0 for r in photos)
    mean = {r["views"]: r["measurement_error_pct"] for r in records if r["method"] == "mean"}
    assert all(r["measurement_error_pct"] < mean[r["views"]] for r in photos)


def test_bench_body_refuses_counts_below_one(capsys):
    from tryon.cli import main

    assert main(["bench", "body", "--people", "0", "--json", "x.json"]) == 2
    assert "--people 0" in capsys.readouterr().err
    assert main(["bench", "body", "--drapes", "-1", "--json", "x.json"]) == 2
    assert "--drapes -1" in capsys.readouterr().err
