"""`tryon bench size`: does `tryon size` recommend, across the BMI range, the size the same
fit rule picks from simulated drapes?

For every bench body (both genders, BMI 18-40) the recommendation is made twice: from the
learned model's drapes (learned + refinement, the default of `tryon size`) and from the
simulator's drapes of every size (`method="simulate"`). Each record holds both sizes,
whether they agree, both wall times (body fit included) and every size's deciding ease (torso, or a skirt's or trousers' hip band) and
overstretched area under each method. The simulated side is the slow one (one full drape
per size; the sizes run as Ray tasks on `workers` CPUs), so bodies are finished one at a
time and their simulated side kept: a stopped bench resumes. The learned side (seconds
per body) is measured afresh on every run.
"""

from __future__ import annotations

import json
from pathlib import Path

from tqdm import tqdm

from tryon.bench.records import write_records
from tryon.sizing.judge import ease_of, target_of
from tryon.body.fit import Measurements

# (gender, height cm, weight kg): BMI about 19, 25, 30 and 35-40 for each gender
BODIES = (("female", 160, 49), ("female", 165, 68), ("female", 168, 85), ("female", 162, 95),
          ("male", 178, 61), ("male", 180, 81), ("male", 176, 93), ("male", 183, 125))
QUICK_BODIES = BODIES[1:2]


def _summary(rec: dict) -> dict:
    return {"recommended": rec["recommended"], "wall_s": rec["wall_s"], "fit_body_s": rec["fit_body_s"],
            "sizes": {j["size"]: {"fits": j["fits"], "torso_ease_cm": j["torso_ease_cm"], "ease_cm": ease_of(j),
                                  "target_ease_cm": target_of(j), "decided_by": j.get("decided_by", "torso"),
                                  "overstrained_area_pct": j["overstrained_area_pct"],
                                  "max_strain_pct": j["max_strain_pct"], "judged_on": j.get("judged_on", "")}
                      for j in rec["sizes"]}}


def bench_body(gender: str, height_cm: float, weight_kg: float, model_path: str | None = None, workers: int = 2,
               kept: dict | None = None) -> dict:
    """Both recommendations for one body. The simulated side of a `kept` record is reused
    (minutes per body); the learned side is always measured again (seconds)."""
    from tryon.sizing.recommend import size_recommendation

    body = Measurements(height_cm=height_cm, weight_kg=weight_kg, gender=gender)
    learned, _ = size_recommendation(body, method="learned", refine=True, model_path=model_path)
    sizes = list(learned["sizes"][i]["size"] for i in range(len(learned["sizes"])))
    if kept and kept["sizes"] == sizes:
        simulated, simulated_s, workers = kept["simulated"], kept["simulated_s"], kept["simulated_workers"]
    else:
        full, _ = size_recommendation(body, method="simulate", model_path=model_path, sizes=sizes, workers=workers)
        simulated, simulated_s = _summary(full), full["wall_s"]
    return {"gender": gender, "height_cm": height_cm, "weight_kg": weight_kg,
            "bmi": weight_kg / (height_cm / 100) ** 2, "sizes": sizes,
            "recommended_learned": learned["recommended"], "recommended_simulated": simulated["recommended"],
            "agree": learned["recommended"] == simulated["recommended"],
            "learned_s": learned["wall_s"], "simulated_s": simulated_s, "simulated_workers": workers,
            "learned": _summary(learned), "simulated": simulated}


def _apply_current_rule(rec: dict) -> None:
    """Both recommendations again from the stored per-size numbers, by the rule as it is now
    (a kept body may have been judged under an earlier rule: nothing is draped again)."""
    from tryon.sizing.judge import recommend

    for method in ("learned", "simulated"):
        sizes = rec[method]["sizes"]
        judged = [{"size": k, "fits": sizes[k]["fits"], "torso_ease_cm": sizes[k]["torso_ease_cm"],
                   **{key: sizes[k][key] for key in ("ease_cm", "target_ease_cm", "decided_by") if key in sizes[k]},
                   "overstrained_area_pct": sizes[k]["overstrained_area_pct"], "why_not": [],
                   "judged_on": sizes[k].get("judged_on", ""), "not_refined": ""} for k in rec["sizes"]]
        rec[method]["recommended"] = rec[f"recommended_{method}"] = recommend(judged)[0]
    rec["agree"] = rec["recommended_learned"] == rec["recommended_simulated"]


def run_size_bench(json_path: str, model_path: str | None = None, quick: bool = False) -> list[dict]:
    """Run the bench (bodies finished earlier, kept in `<json>.bodies/`, are reused), print
    a table and write the records."""
    json_path = Path(json_path)
    keep = json_path.with_name(json_path.name + ".bodies")
    keep.mkdir(parents=True, exist_ok=True)
    records = []
    for gender, height, weight in tqdm(QUICK_BODIES if quick else BODIES, desc="size bench bodies", disable=None):
        path = keep / f"{gender}-{height}-{weight}.json"
        kept = json.loads(path.read_text()) if path.exists() else None
        rec = bench_body(gender, height, weight, model_path, kept=kept)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(rec, indent=2))
        tmp.replace(path)
        _apply_current_rule(rec)
        records.append(rec)
        print(f"{gender:<6} {height} cm / {weight} kg (BMI {rec['bmi']:.1f}): learned {rec['recommended_learned']} "
              f"in {rec['learned_s']:.1f} s, simulated {rec['recommended_simulated']} in {rec['simulated_s']:.0f} s"
              f"{'' if rec['agree'] else '  (differ)'}")
    agree = sum(r["agree"] for r in records)
    print(f"{agree} of {len(records)} bodies: the learned recommendation is the simulated one")
    write_records(str(json_path), records, model=model_path or "shipped")
    return records
