"""The `tryon` command: simulate, fabrics, bench, errors."""

import json
import subprocess
import sys

import numpy as np
import pytest

from tryon.cli import main


def test_simulate_example_writes_all_outputs(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["simulate", "--example", "sphere-drop", "--resolution", "8", "--duration", "0.12", "--out", str(out), "--quiet"])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    for key in ("steps", "wall_s", "max_strain", "min_obstacle_distance", "intersections"):
        assert key in summary
    assert summary["steps"] == 12 and summary["intersections"] == 0
    frames = np.load(out / "frames.npz")
    assert frames["positions"].shape[1:] == (64, 3)
    assert (out / "obj" / "frame_0000.obj").exists()
    from PIL import Image

    img = np.asarray(Image.open(out / "last_frame.png"))
    assert img.shape[0] >= 400 and img.std() > 5  # a real picture, not a blank
    assert not (tmp_path / "run.partial").exists()


def test_simulate_yaml(tmp_path):
    scene = tmp_path / "s.yaml"
    scene.write_text("dt: 0.01\nduration: 0.03\ncloth:\n  grid: {resolution: [5, 5]}\n  pins: [top-left, top-right]\n")
    rc = main(["simulate", str(scene), "--out", str(tmp_path / "o"), "--quiet", "--no-obj"])
    assert rc == 0
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["steps"] == 3


def test_bad_input_gives_one_line_error_and_no_output(tmp_path, capsys):
    scene = tmp_path / "bad.yaml"
    scene.write_text("cloth:\n  grid: {resolution: [5, 5]}\n  fabric: velvet\n")
    rc = main(["simulate", str(scene), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("error:") and "velvet" in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_unknown_example(capsys):
    assert main(["simulate", "--example", "nope"]) == 2
    assert "hanging" in capsys.readouterr().err


def test_fabrics_lists_presets(capsys):
    assert main(["fabrics"]) == 0
    out = capsys.readouterr().out
    assert "gray-interlock" in out and "11oz-black-denim" in out
    assert main(["fabrics", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == 12


@pytest.mark.slow
def test_bench_sim_quick(tmp_path):
    out = tmp_path / "bench.json"
    rc = subprocess.run([sys.executable, "-m", "tryon.cli", "bench", "sim", "--quick", "--grids", "16", "--threads", "1", "--json", str(out)],
                        capture_output=True, text=True)
    assert rc.returncode == 0, rc.stderr
    recs = json.loads(out.read_text())
    assert {r["scene"] for r in recs} == {"hanging", "sphere-drop"}
    for r in recs:
        for key in ("scene", "grid", "vertices", "dt", "threads", "s_per_step"):
            assert key in r
        assert r["s_per_step"] > 0 and "speedup_vs_arcsim" in r


def test_robustness_check_reports_a_passing_run():
    from tryon.bench.robustness import check_one

    rec = check_one("hanging", "gray-interlock", 1 / 30, resolution=6, duration=0.1)
    assert rec["ok"] and rec["finite"] and rec["intersections"] == 0
    assert rec["steps"] == 3
