"""`tryon bench drape --matrix`: every garment on bodies across the supported range.

Each garment (tshirt, longsleeve, skirt, trousers, dress; the dress only on women) is
draped in the standard size nearest each body (tops and dresses by chest, skirts and
trousers by hip, from the body's own fitted girths), in a woven and a knit fabric, on
twelve bodies: both genders, BMI 17-45, heights 150-200 cm. Every cell is a real
`tryon drape` run in its own process (renders, fit maps and GLB in the cell's folder);
a cell that fails or exceeds its time limit is recorded with the reason. Finished cells
are kept, so a stopped matrix resumes where it stopped. A body beyond the largest size
(`tryon drape` refuses a size far too small) gets the garment made to measure, with the
reason recorded. `--quick`: two bodies, one fabric, 3 cm edges.

Pass (the issue's bar): every cell settles, with 0 % penetration, no explosion, in under
`TARGET_S` seconds including body fit and sewing.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from tryon.errors import TryonError
from tryon.io.atomic import atomic_write, claim_work_dir
from tryon.io.json_safe import dumps_json
from tryon.sizing.chart import chart_size, fitted_girths

TARGET_S = 60.0
# A cell's simulated drape stops with the drape's own diagnosis after this long (a pass
# needs far less); the process limit (`timeout_s`) also covers body fit and dressing.
SIM_LIMIT_S = 2 * TARGET_S
GARMENTS = ("tshirt", "longsleeve", "skirt", "trousers", "dress")
FABRICS = ("11oz-black-denim", "gray-interlock")  # a woven, a knit


@dataclass(frozen=True)
class Body:
    gender: str
    height_cm: float
    bmi: float

    @property
    def weight_kg(self) -> float:
        return round(self.bmi * (self.height_cm / 100.0) ** 2, 1)

    @property
    def key(self) -> str:
        return f"{self.gender[0]}{self.height_cm:.0f}-bmi{self.bmi:.0f}"


BODIES = (
    Body("female", 150, 17), Body("female", 158, 37), Body("female", 163, 22), Body("female", 168, 28),
    Body("female", 175, 45), Body("female", 182, 24),
    Body("male", 160, 20), Body("male", 170, 26), Body("male", 176, 17), Body("male", 184, 32),
    Body("male", 192, 40), Body("male", 200, 45),
)
QUICK_BODIES = (Body("female", 165, 22), Body("male", 180, 25))


def body_girths(body: Body) -> dict:
    from tryon.body.fit import Measurements, fit_body

    return fitted_girths(fit_body(Measurements(height_cm=body.height_cm, weight_kg=body.weight_kg, gender=body.gender)))


def cells(quick: bool, keys: list[str] | None = None) -> list[tuple[Body, str, str]]:
    """The matrix's (body, garment, fabric) cells; `keys`: only these bodies' rows."""
    bodies = QUICK_BODIES if quick else BODIES
    if keys:
        unknown = sorted(set(keys) - {b.key for b in bodies})
        if unknown:
            raise TryonError(f"no matrix body {', '.join(unknown)}; the bodies are {', '.join(b.key for b in bodies)}")
        bodies = tuple(b for b in bodies if b.key in keys)
    fabrics = FABRICS[1:] if quick else FABRICS
    return [(b, g, f) for b in bodies for g in GARMENTS for f in fabrics if not (g == "dress" and b.gender == "male")]


def _drape_cell(body: Body, garment: str, size: str, fabric: str, edge: float, out: Path, timeout_s: float) -> dict:
    cmd = [sys.executable, "-m", "tryon.cli", "drape", "--height-cm", str(body.height_cm), "--weight-kg",
           str(body.weight_kg), "--gender", body.gender, "--garment", garment, "--size", size.lower(),
           "--fabric", fabric, "--edge-length", str(edge), "--out", str(out), "--quiet",
           "--time-limit", str(SIM_LIMIT_S)]
    tic = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return {"error": f"stopped after {timeout_s:.0f} s", "wall_s": time.perf_counter() - tic}
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines()
        return {"error": lines[-1] if lines else f"exit {proc.returncode}", "wall_s": time.perf_counter() - tic}
    rep = json.loads((out / "report.json").read_text())
    return {"wall_s": rep["wall_s"], "process_s": time.perf_counter() - tic, "settled": bool(rep.get("settled")),
            "final_speed": rep.get("final_max_speed"), "max_speed": rep.get("max_speed"), "steps": rep.get("steps"),
            "retries": rep.get("retried_steps"), "substeps": rep.get("substeps"),
            "penetration_pct": rep["penetration_pct"], "max_strain": rep["max_strain"],
            "recovered": len(rep.get("speed_recoveries", [])), "dress_cached": bool(rep.get("dressing", {}).get("cached")),
            "dress_s": rep.get("timings", {}).get("dress_s")}


def passed(rec: dict) -> bool:
    return ("error" not in rec and rec["settled"] and rec["penetration_pct"] == 0.0
            and rec["wall_s"] < TARGET_S and (rec.get("max_speed") is None or rec["max_speed"] < 10.0))


def run_drape_matrix(json_path: str | Path, quick: bool = False, edge_length: float | None = None,
                     timeout_s: float = 360.0, bodies: list[str] | None = None) -> list[dict]:
    """Drape every cell (resuming finished ones; `bodies`: only those rows, the others
    kept in the JSON as the last run wrote them), print the table, write JSON and the
    picture grid (`<json stem>.png`); cell folders in `<json stem>-cells/`."""
    json_path = Path(json_path)
    edge = edge_length or (0.03 if quick else 0.012)
    cell_root = claim_work_dir(json_path.with_name(json_path.stem + "-cells"), resume=True)
    girths: dict[str, dict] = {}
    records = []
    print(f"{'garment':10s} {'size':4s} {'fabric':17s} {'body':14s} {'wall s':>7s} {'steps':>5s} {'settled':>7s} "
          f"{'pen %':>6s} {'strain':>6s}  result")
    for body, garment, fabric in cells(quick, bodies):
        if body.key not in girths:
            girths[body.key] = body_girths(body)
        size, why = chart_size(garment, girths[body.key], body.gender)
        name = f"{garment}-{size}-{fabric}-{body.key}"
        done = cell_root / f"{name}.json"
        if done.exists():
            rec = json.loads(done.read_text())
        else:
            res = _drape_cell(body, garment, size, fabric, edge, cell_root / name, timeout_s)
            rec = {"garment": garment, "size": size, "fabric": fabric, "gender": body.gender,
                   "height_cm": body.height_cm, "weight_kg": body.weight_kg, "bmi": body.bmi, "edge_length_m": edge,
                   "cell": name, **girths[body.key], **res}
            if why:
                rec["size_note"] = f"made to measure: {why}"
            rec["passed"] = passed(rec)
            with atomic_write(done) as fh:
                fh.write(dumps_json(rec, indent=2))
        records.append(rec)
        _print_row(rec)
    if bodies and json_path.exists():  # the other rows as the last run left them
        chosen = {(b.gender, b.height_cm, b.bmi) for b, _, _ in cells(quick, bodies)}
        kept = [r for r in json.loads(json_path.read_text()) if (r["gender"], r["height_cm"], r["bmi"]) not in chosen]
        records = kept + records
    with atomic_write(json_path) as fh:
        fh.write(dumps_json(records, indent=2))
    picture = picture_grid(records, cell_root, json_path.with_suffix(".png"))
    ok = sum(r["passed"] for r in records)
    print(f"{ok} of {len(records)} cells pass (settled, 0 % penetration, under {TARGET_S:.0f} s) -> {json_path}, {picture}")
    return records


def _print_row(r: dict) -> None:
    body = f"{r['gender'][0]} {r['height_cm']:.0f}/{r['weight_kg']:.0f}"
    if "error" in r:
        print(f"{r['garment']:10s} {r['size']:4s} {r['fabric']:17s} {body:14s} {r['wall_s']:7.1f}  failed: {r['error']}")
        return
    print(f"{r['garment']:10s} {r['size']:4s} {r['fabric']:17s} {body:14s} {r['wall_s']:7.1f} {r['steps']:5d} "
          f"{str(r['settled']):>7s} {r['penetration_pct']:6.2f} {100 * r['max_strain']:5.1f}%  "
          f"{'pass' if r['passed'] else 'FAIL'}")


def picture_grid(records: list[dict], cell_root: Path, path: Path, tile: tuple[int, int] = (150, 200)) -> Path:
    """Front renders of every cell, one row per body, failed cells framed in red."""
    from PIL import Image, ImageDraw

    from tryon.render.colormap import label_font

    rows = sorted({(r["gender"], r["height_cm"], r["bmi"]) for r in records})
    cols = sorted({(r["garment"], r["fabric"]) for r in records}, key=lambda c: (GARMENTS.index(c[0]), c[1]))
    w, h = tile
    label_h = 28
    sheet = Image.new("RGB", (w * len(cols), (h + label_h) * len(rows)), "white")
    draw = ImageDraw.Draw(sheet)
    font = label_font(11)
    for r in records:
        i = rows.index((r["gender"], r["height_cm"], r["bmi"]))
        j = cols.index((r["garment"], r["fabric"]))
        x0, y0 = j * w, i * (h + label_h)
        render = cell_root / r["cell"] / "render_front.png"
        if render.exists():
            img = Image.open(render).convert("RGB")
            img.thumbnail((w, h))
            sheet.paste(img, (x0 + (w - img.width) // 2, y0 + label_h))
        colour = (20, 120, 40) if r["passed"] else (200, 30, 30)
        text = f"{r['garment']} {r['size']} {r['fabric'].split('-')[0]}\n{r['gender'][0]} {r['height_cm']:.0f} cm BMI {r['bmi']:.0f}"
        draw.multiline_text((x0 + 4, y0 + 2), text, fill=colour, font=font, spacing=1)
        if not r["passed"]:
            draw.rectangle([x0 + 1, y0 + 1, x0 + w - 2, y0 + h + label_h - 2], outline=colour, width=3)
    with atomic_write(path, "wb") as fh:
        sheet.save(fh, format="PNG")
    return path
