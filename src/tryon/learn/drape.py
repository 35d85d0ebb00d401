"""`tryon drape --method learned`: the drape predicted by a trained network (tryon.learn)
instead of simulated, measured and written exactly like a simulated one.

The person is fitted and A-posed as for simulation; the model predicts the garment of
the asked size on that body in milliseconds; the fit metrics (strain against the size's
rest shape, contact pressure, penetration) come from the same simulator model the
simulated path uses, so the two reports compare directly."""

from __future__ import annotations

import time

from tryon.body.fit import fit_body
from tryon.body.measure import drafting_measurements
from tryon.body.pose import posed_body
from tryon.drape.pipeline import DrapeRequest, DrapeResult, check_size_fits
from tryon.errors import TryonError


def learned_drape(request: DrapeRequest, model_path: str | None = None, refine: bool = False, person=None,
                  model=None, refine_until=None) -> DrapeResult:
    """The drape of `request` predicted by the learned model (the shipped one of the garment,
    or `model_path`); with `refine`, relaxed by the simulator (tryon.learn.refine) until at
    rest, or until the observer `refine_until(garment, posed body)` makes ends the run. A
    caller draping several sizes passes the fitted `person` and the loaded `model` once."""
    from tryon.drape.dress import cloth_on_body
    from tryon.drape.fit_metrics import drape_metrics
    from tryon.fabric import load_fabric
    from tryon.learn.model import DrapeModel, load_shipped
    from tryon.sim.integrator import ImplicitEulerSolver
    from tryon.sim.obstacles import Obstacle

    request.validate()
    if request.size is None or request.garment_obj is not None:
        raise TryonError("the learned drape knows standard sizes of its garments; use --method simulate for "
                         "made-to-measure or OBJ garments")
    size = request.size.upper()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if model is None:
        model = DrapeModel.load(model_path) if model_path else load_shipped(request.garment)
    garment = model.reference_garment(request.body.gender, size)
    request.graphic_print(garment)  # a print that does not fit is refused before the body is fitted
    timings["load_model_s"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    person = person or fit_body(request.body)
    check_size_fits(request, person)  # a size far too small is refused, as by the simulated path
    target = posed_body(person.shape, "a", drafting_measurements(person.shape)["crotch_height"])
    timings["fit_body_s"] = time.perf_counter() - t1
    fabric = load_fabric(request.fabric)
    t2 = time.perf_counter()
    x = model.predict_vertices(target.vertices, request.body.gender, size, fabric)
    timings["inference_ms"] = 1000.0 * (time.perf_counter() - t2)
    refined: dict = {}
    if refine:
        from tryon.learn.refine import refine_drape

        x, refined = refine_drape(x, garment, target, fabric, request.thickness, request.friction,
                                  request.dt, rest_speed=request.rest_speed, regions=request.material_regions(garment),
                                  until=refine_until(garment, target) if refine_until else None)
        timings["refine_s"] = refined["refine_s"]
    result = DrapeResult(request, person, None, garment, target.vertices, target.faces, x, [x], [0.0], timings=timings)
    t3 = time.perf_counter()
    body = Obstacle("body", target.vertices, target.faces)
    sim_model = cloth_on_body(garment.cloth_mesh(x), fabric, body, request.thickness,
                              friction=request.friction, regions=request.material_regions(garment))
    result.metrics = drape_metrics(result, ImplicitEulerSolver(sim_model))
    result.metrics.update(refined)
    result.metrics["notes"] = model.coverage_notes(request.body.gender, person.achieved["height_cm"], person.achieved["bmi"],
                                                   fabric)
    result.metrics.update({"method": "learned+refine" if refine else "learned", "model": model.card.get("trained", "?"), "steps": refined.get("refine_steps", 0),
                           "settled": refined["refine_final_speed"] <= request.rest_speed if refine else None,
                           "simulated_s": 0.0, "morph_s": 0.0, "speed_recoveries": [], "failsafe_steps": 0})
    timings["metrics_s"] = time.perf_counter() - t3
    timings["wall_s"] = time.perf_counter() - t0
    return result
