"""`tryon bench anthropometry`: are tryon's bodies like real people's?

On ANSUR II people held out from the prior (`tryon.body.prior.held_out`), a fixed subset
spread over each sex's BMI range, every body is built as a user would build it and
measured with the tapes of `tryon.body.tape`, against what the survey measured on the
person. Modes:

* `height-weight`: `fit_body` from stature, weight, sex and age (the prior fills the rest);
* `height-weight-girths`: the same plus the person's chest, waist (at the navel) and hip;
* `regression`: the prior's own prediction from stature, weight and age, no body;
* `anny-average`: the pinned fit (`prior=False`): Anny's average shape of that stature
  and weight, what tryon built before the prior.

One record per mode and measurement: `mean_abs_cm`, `mean_rel_pct`, `bias_cm` (body minus
person), `fit_s` (mean fit time), `people`, and, for the bodies, `ratio_to_regression`
(mean relative error over the regression's).
"""

from __future__ import annotations

import time

import numpy as np
from tqdm import tqdm

from tryon.bench.records import one_torch_thread, write_records
from tryon.body.fit import BMI_RANGE, HEIGHT_RANGE_CM, Measurements, fit_body
from tryon.body.prior import Person, default_prior, held_out, load_ansur
from tryon.body.tape import tape_measurements

MEASURED = ("chest_cm", "waist_navel_cm", "hip_cm", "neck_cm", "thigh_cm", "crotch_height_cm", "waist_height_cm",
            "shoulder_width_cm", "arm_length_cm", "wrist_cm")
GIRTHS_GIVEN = ("chest_cm", "waist_navel_cm", "hip_cm")
MODES = ("height-weight", "height-weight-girths", "regression", "anny-average")


def bench_people(per_sex: int) -> list[Person]:
    """`per_sex` held-out people of each sex inside tryon's supported range, evenly spaced
    in BMI order (the same people on every run)."""
    _, test = held_out(load_ansur())
    chosen = []
    for sex in ("male", "female"):
        group = sorted((p for p in test if p.gender == sex and BMI_RANGE[sex][0] <= p.bmi <= BMI_RANGE[sex][1]
                        and HEIGHT_RANGE_CM[0] <= p.height_cm <= HEIGHT_RANGE_CM[1]), key=lambda p: (p.bmi, p.subject))
        idx = np.unique(np.linspace(0, len(group) - 1, per_sex).round().astype(int))
        chosen += [group[i] for i in idx]
    return chosen


def _measure(person: Person, mode: str) -> tuple[dict[str, float], float]:
    """The measurements (cm) of the body (or the regression) of one mode, and its time."""
    t0 = time.perf_counter()
    if mode == "regression":
        pred = default_prior().predict(person.gender, person.height_cm, person.age, {"weight_kg": person.values["weight_kg"]})
        return pred.mean, time.perf_counter() - t0
    m = Measurements(height_cm=person.height_cm, weight_kg=person.values["weight_kg"], gender=person.gender,
                     age=min(max(person.age, 16.0), 90.0))
    if mode == "height-weight-girths":
        for key in GIRTHS_GIVEN:
            setattr(m, key, person.values[key])
    fit = fit_body(m, prior=mode != "anny-average")
    fit_s = time.perf_counter() - t0
    return tape_measurements(fit.shape), fit_s


def summarise(rows: dict[str, list[tuple[Person, dict, float]]]) -> list[dict]:
    records = []
    reg_rel = {}
    for mode in MODES:
        if mode not in rows:
            continue
        for key in MEASURED:
            if mode == "height-weight-girths" and key in GIRTHS_GIVEN:
                label = "given"
            else:
                label = "predicted"
            err = np.array([out[key] - p.values[key] for p, out, _ in rows[mode]])
            rel = np.array([abs(out[key] - p.values[key]) / p.values[key] for p, out, _ in rows[mode]])
            rec = {"mode": mode, "measurement": key.removesuffix("_cm"), "mean_abs_cm": float(np.abs(err).mean()),
                   "mean_rel_pct": 100.0 * float(rel.mean()), "bias_cm": float(err.mean()),
                   "fit_s": float(np.mean([t for *_, t in rows[mode]])), "people": len(rows[mode]), "role": label}
            if mode == "regression":
                reg_rel[key] = rec["mean_rel_pct"]
            records.append(rec)
    for rec in records:
        ref = reg_rel.get(rec["measurement"] + "_cm")
        if rec["mode"] != "regression" and ref:
            rec["ratio_to_regression"] = rec["mean_rel_pct"] / ref
    return records


def run_anthropometry_bench(json_path: str, per_sex: int = 30, modes: tuple[str, ...] = MODES) -> list[dict]:
    people = bench_people(per_sex)
    rows: dict[str, list] = {}
    with one_torch_thread():
        for mode in modes:
            rows[mode] = []
            for p in tqdm(people, desc=f"anthropometry {mode}", unit="body", disable=mode == "regression"):
                out, seconds = _measure(p, mode)
                rows[mode].append((p, out, seconds))
    records = summarise(rows)
    write_records(json_path, records, bench="anthropometry", per_sex=per_sex,
                  data="ANSUR II held-out people (tryon.body.prior.held_out)")
    _print_table(records)
    return records


def _print_table(records: list[dict]) -> None:
    print(f"{'mode':22s} {'measurement':16s} {'abs cm':>7s} {'rel %':>6s} {'bias cm':>8s} {'x regr':>7s} {'fit s':>6s}")
    for r in records:
        ratio = f"{r['ratio_to_regression']:.2f}" if "ratio_to_regression" in r else ""
        print(f"{r['mode']:22s} {r['measurement']:16s} {r['mean_abs_cm']:7.2f} {r['mean_rel_pct']:6.2f} "
              f"{r['bias_cm']:+8.2f} {ratio:>7s} {r['fit_s']:6.2f}")
