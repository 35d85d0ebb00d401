"""`tryon bench learned`, on people outside the dataset: `tryon drape --method learned
--refine` against `tryon drape` (the simulator, at its own default settings: another
triangulation than the model's) for the same body, size and fabric.

The bodies are fixed here, none drawn by the dataset's sampler; each wears the standard
size nearest its chest that `tryon drape` accepts. The two garments have different meshes,
so they are compared by mean surface distance: each garment's vertices to the other's
surface, both ways, averaged. One record per body: `method` `learned+refine`, `split`
`outside-dataset`, `mean_surface_distance_cm`, `interpenetration_pct` (the learned drape's,
as the drape report measures it), `learned_s` and `simulation_s` (each path's wall time,
body fit included)."""

from __future__ import annotations

import time

import numpy as np

# (gender, height cm, weight kg): BMI about 20, 26, 22 and 28
OUTSIDE_BODIES = (("female", 157, 50), ("female", 171, 77), ("male", 169, 64), ("male", 189, 100))


def mean_surface_distance_cm(a_v: np.ndarray, a_f: np.ndarray, b_v: np.ndarray, b_f: np.ndarray) -> float:
    """Symmetric mean distance (cm) between two triangle meshes: each one's vertices to the
    other's surface, the two means averaged."""
    from tryon.sim.geometry import nearest_surface_points

    ab = np.abs(nearest_surface_points(np.asarray(a_v, np.float64), np.asarray(b_v, np.float64), b_f)[0])
    ba = np.abs(nearest_surface_points(np.asarray(b_v, np.float64), np.asarray(a_v, np.float64), a_f)[0])
    return float(50.0 * (ab.mean() + ba.mean()))  # signed distances to an open surface: their size counts


def outside_body_record(gender: str, height_cm: float, weight_kg: float, model, fabric: str) -> dict:
    """Both drapes of one body and how far apart they are."""
    from tryon.sizing.chart import chart_size, fitted_girths
    from tryon.body.fit import Measurements, fit_body
    from tryon.drape import drape
    from tryon.drape.pipeline import DrapeRequest
    from tryon.learn.drape import learned_drape

    body = Measurements(height_cm=height_cm, weight_kg=weight_kg, gender=gender)
    t0 = time.perf_counter()
    person = fit_body(body)  # the learned side's fit, timed with it; it also picks the size
    size = chart_size(model.garment, fitted_girths(person), gender)[0]
    if size not in model.sizes:
        raise ValueError(f"the {height_cm} cm / {weight_kg} kg {gender} wears {size}, which the model does not know")
    req = DrapeRequest(body, garment=model.garment, size=size, fabric=fabric)
    learned = learned_drape(req, refine=True, person=person, model=model)
    t1 = time.perf_counter()
    simulated = drape(req, progress=False)
    t2 = time.perf_counter()
    return {"method": "learned+refine", "split": "outside-dataset", "gender": gender, "height_cm": height_cm,
            "weight_kg": weight_kg, "size": size, "fabric": fabric,
            "mean_surface_distance_cm": mean_surface_distance_cm(learned.x, learned.garment.faces, simulated.x,
                                                                 simulated.garment.faces),
            "interpenetration_pct": float(learned.metrics["penetration_pct"]),
            "simulated_interpenetration_pct": float(simulated.metrics["penetration_pct"]),
            "vertices": {"learned": len(learned.x), "simulated": len(simulated.x)},
            "learned_s": t1 - t0, "simulation_s": t2 - t1}


def outside_dataset_records(model, fabric: str, bodies=OUTSIDE_BODIES, progress: bool = True) -> list[dict]:
    from tryon.bench.records import progress_line

    records = []
    for g, h, w in bodies:
        records.append(outside_body_record(g, h, w, model, fabric))
        if progress:
            progress_line("learned", f"outside the dataset: {len(records)} of {len(bodies)} people ({g}, {h:g} cm, {w:g} kg)")
    return records
