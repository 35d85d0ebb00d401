"""`tryon bench drape --matrix --bodies`: re-running some rows keeps the others' records."""

import json

from tryon.bench import drape_matrix


def test_rerunning_some_rows_keeps_the_other_rows(tmp_path, monkeypatch):
    monkeypatch.setattr(drape_matrix, "body_girths", lambda body: {"chest_cm": 90.0, "waist_cm": 75.0, "hip_cm": 95.0})
    runs = []

    def drape_cell(body, garment, size, fabric, edge, out, timeout_s):
        runs.append(body.key)
        return {"wall_s": 10.0 + len(runs), "settled": True, "penetration_pct": 0.0, "max_strain": 0.1, "steps": 9}

    monkeypatch.setattr(drape_matrix, "_drape_cell", drape_cell)
    monkeypatch.setattr(drape_matrix, "picture_grid", lambda records, root, path: path)
    out = tmp_path / "matrix.json"
    everything = drape_matrix.run_drape_matrix(out, quick=True)
    keys = [b.key for b in drape_matrix.QUICK_BODIES]
    assert len(everything) == 2 * len(drape_matrix.GARMENTS) - 1 and set(runs) == set(keys)
    # re-run the first body's row (its finished cells removed): the second row stays as it was
    for cell in (tmp_path / "matrix-cells").glob(f"*{keys[0]}.json"):
        cell.unlink()
    runs.clear()
    drape_matrix.run_drape_matrix(out, quick=True, bodies=[keys[0]])
    assert set(runs) == {keys[0]}
    after = json.loads(out.read_text())
    assert len(after) == len(everything)
    second = [r for r in after if r["cell"].endswith(keys[1])]
    assert second == [json.loads(json.dumps(r)) for r in everything if r["cell"].endswith(keys[1])]
