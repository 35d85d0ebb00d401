"""`tryon bench drape`: the try-on job timed end to end. A T-shirt in size M and
gray-interlock on bodies of BMI about 18, 25 and 35, both genders, at about 1 cm edge
length: wall time (split into body fitting, dressing, simulation), vertices inside the
body, max and mean strain, against the target of 60 s per drape on a 2-core machine.

Dressing is cached per pattern, fit model and edge length (as in normal use), so the
first drape of a gender pays for sewing the size-M T-shirt and later ones do not; both
are reported. Each drape runs in its own process with a fresh torch thread pool.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tryon.io.atomic import atomic_write
from tryon.io.json_safe import dumps_json

TARGET_S = 60.0
HEIGHT_CM = {"female": 165.0, "male": 178.0}
BMIS = (18.0, 25.0, 35.0)


def _one(gender: str, bmi: float, edge_length: float, threads: int, timeout_s: float) -> dict:
    code = (
        "import json, numba, torch; torch.set_num_threads(%d); numba.set_num_threads(min(%d, numba.config.NUMBA_NUM_THREADS))\n"
        "from tryon.body.fit import Measurements\n"
        "from tryon.drape import DrapeRequest, drape\n"
        "r = drape(DrapeRequest(Measurements(height_cm=%r, bmi=%r, gender=%r), garment='tshirt', size='M',\n"
        "          fabric='gray-interlock', edge_length=%r, allow_tight=True), progress=False)\n"
        "m = r.metrics\n"
        "print(json.dumps({'wall_s': r.timings['wall_s'], 'timings': r.timings, 'vertices_inside': m['vertices_inside'],\n"
        "  'penetration_pct': m['penetration_pct'], 'max_strain': m['max_strain'], 'mean_strain': m['mean_strain'],\n"
        "  'overstrained_area_pct': m['overstrained_area_pct'], 'steps': m['steps'], 'settled': m['settled'],\n"
        "  'retried_steps': m['retried_steps'], 'garment_vertices': int(len(r.garment.vertices)),\n"
        "  'dressing_cached': bool(r.garment.stats.get('cached', False)), 'bmi_achieved': r.person.achieved['bmi']}))\n"
    ) % (threads, threads, HEIGHT_CM[gender], bmi, gender, edge_length)
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout_s:.0f} s"}
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run_drape_bench(json_path: str | Path, quick: bool = False, threads: int = 2, edge_length: float = 0.01,
                    timeout_s: float = 900.0) -> list[dict]:
    """Run the drapes (quick: one female BMI 25 drape at 3 cm), print a table, write JSON.
    A drape still running after `timeout_s` is stopped and recorded as an error."""
    cases = [("female", 25.0)] if quick else [(g, b) for g in ("female", "male") for b in BMIS]
    edge = 0.03 if quick else edge_length
    records = []
    print(f"{'gender':7s} {'BMI':>5s} {'verts':>6s} {'wall s':>7s} {'dress s':>8s} {'sim s':>6s} {'inside':>6s} "
          f"{'max strain':>10s} {'mean':>6s} {'x target':>8s}")
    for gender, bmi in cases:
        res = _one(gender, bmi, edge, threads, timeout_s)
        rec = {"garment": "tshirt", "size": "M", "fabric": "gray-interlock", "gender": gender, "height_cm": HEIGHT_CM[gender],
               "bmi": bmi, "edge_length_m": edge, "threads": threads, "target_s": TARGET_S, **res}
        if "error" not in res:
            rec["target_ratio"] = TARGET_S / res["wall_s"]
            t = res["timings"]
            print(f"{gender:7s} {bmi:5.1f} {res['garment_vertices']:6d} {res['wall_s']:7.1f} {t['dress_s']:8.1f} "
                  f"{t['simulate_s']:6.1f} {res['vertices_inside']:6d} {100 * res['max_strain']:9.1f}% "
                  f"{100 * res['mean_strain']:5.1f}% {rec['target_ratio']:7.2f}x")
        else:
            print(f"{gender:7s} {bmi:5.1f} failed: {res['error']}")
        records.append(rec)
    Path(json_path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(json_path) as fh:
        fh.write(dumps_json(records, indent=2))
    return records
