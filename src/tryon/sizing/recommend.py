"""Every size of a garment draped on a person and judged (`tryon size`).

Every size the learned model knows is draped on the person (learned + refinement, or
simulated with `method="simulate"`) and judged by `tryon.sizing.judge`.

Refinement is the slow part, and slowest on a size far too small (the simulator fights
the strain). A smaller size is tighter everywhere, so the learned path refines from the
largest size down and stops as soon as the answer is settled: at a size that does not fit
(every smaller one is tighter still) or at one that fits closer than a regular fit (every
smaller one is farther from it). Sizes below the stop keep their prediction's numbers,
marked `"judged_on": "prediction"`, and are not candidates."""

from __future__ import annotations

import time

from tryon.body.fit import Measurements, fit_body
from tryon.drape.pipeline import DrapeRequest, DrapeResult
from tryon.errors import TryonError
from tryon.sizing.judge import ease_of, judge_size, recommend, target_of, undrapeable


def _drape_or_reason(req: DrapeRequest, person=None) -> DrapeResult | str:
    """`tryon drape` of the request (on `person`, the body fitted already, when given), or
    why the simulator could not drape it (a size far too small for the body)."""
    from tryon.drape import drape
    from tryon.errors import SimulationError

    try:
        return drape(req, progress=False, person=person)
    except SimulationError as exc:
        return str(exc)


def _simulated_task(req: DrapeRequest, person=None) -> DrapeResult | str:
    from tryon.parallel.executors import one_thread_per_worker

    one_thread_per_worker()
    return _drape_or_reason(req, person)


def simulated_drapes(requests: list[DrapeRequest], workers: int = 1, ray_address: str | None = None,
                     person=None) -> list[DrapeResult | str]:
    """`tryon drape` of every request (or why it could not be draped): in this process, or
    as Ray tasks (one CPU each) when `workers` > 1 or a cluster address is given. `person`:
    the body fitted once for all of them."""
    if workers <= 1 and not ray_address:
        return [_drape_or_reason(req, person) for req in requests]
    from tryon.parallel.executors import connect_ray

    started = connect_ray(ray_address, workers)
    import ray

    try:
        task = ray.remote(num_cpus=1, max_retries=1)(_simulated_task)
        body = ray.put(person)
        return ray.get([task.remote(req, body) for req in requests])
    finally:
        if started:
            ray.shutdown()


def learned_sizes(requests: list[DrapeRequest], person, model, refine: bool = True) -> tuple[list[DrapeResult], list[dict]]:
    """(the drape, the judgement) of every size of `requests` (smallest first): with
    `refine`, refined from the largest down until the answer is settled (the module's
    docstring says when), the sizes below that predicted only; else every size predicted."""
    from tryon.learn.drape import learned_drape
    from tryon.sizing.quick import refined_for_judging

    def predicted(req: DrapeRequest) -> tuple[DrapeResult, dict]:
        r = learned_drape(req, person=person, model=model)
        return r, dict(judge_size(req.size, r, strain_reliable=False), judged_on="prediction")

    if not refine:
        pairs = [predicted(req) for req in requests]
        return [r for r, _ in pairs], [j for _, j in pairs]
    results, judged = [None] * len(requests), [None] * len(requests)
    for k in reversed(range(len(requests))):
        results[k] = refined_for_judging(requests[k], person, model)
        judged[k] = dict(judge_size(requests[k].size, results[k]), judged_on="refined drape")
        size = judged[k]["size"]
        if not judged[k]["fits"]:
            why = f"smaller than {size}, which does not fit"
        elif ease_of(judged[k]) <= target_of(judged[k]):
            why = f"smaller than {size}, which already fits closer than a regular fit"
        else:
            continue
        for i in range(k):
            results[i], judged[i] = predicted(requests[i])
            judged[i]["not_refined"] = why
            if not judged[k]["fits"]:  # tighter than a size that does not fit
                judged[i].update(fits=False, why_not=judged[i]["why_not"] or [f"it is {why}"])
        break
    return results, judged


def size_recommendation(body: Measurements, garment: str = "tshirt", fabric: str = "gray-interlock",
                        method: str = "learned", refine: bool = True, model_path: str | None = None,
                        sizes: list[str] | None = None, workers: int = 1,
                        ray_address: str | None = None, person=None) -> tuple[dict, list[DrapeResult | str]]:
    """(the recommendation as a dict, the drape of every size). `method="simulate"` drapes
    the sizes as Ray tasks when `workers` > 1 or `ray_address` names a cluster. `person`:
    `fit_body(body)` when the caller has it already (a body from photos)."""
    from tryon.learn.model import DrapeModel, load_shipped

    if method not in ("learned", "simulate"):
        raise TryonError(f"unknown method {method!r}; use learned or simulate")
    from tryon.garment.sizes import SIZES

    t0 = time.perf_counter()
    model = None
    if method == "learned" or not sizes:
        model = DrapeModel.load(model_path) if model_path else load_shipped(garment)
    sizes = sorted({s.upper() for s in (sizes or model.sizes)}, key=lambda s: SIZES.index(s) if s in SIZES else 99)
    DrapeRequest(body, garment=garment, size=sizes[0], fabric=fabric).validate()
    person = person or fit_body(body)
    fit_s = time.perf_counter() - t0
    # a size far too small is judged by how it strains, not refused
    requests = [DrapeRequest(body, garment=garment, size=size, fabric=fabric, allow_tight=True) for size in sizes]
    if method == "learned":
        results, judged = learned_sizes(requests, person, model, refine)
    else:
        results = simulated_drapes(requests, workers, ray_address, person)
        judged = [undrapeable(s, r, garment) if isinstance(r, str) else dict(judge_size(s, r), judged_on="simulated drape")
                  for s, r in zip(sizes, results)]
    draped = [r for r in results if not isinstance(r, str)]
    if not draped:
        raise TryonError(f"no size of the {garment} could be draped on this body: " + "; ".join(judged[-1]["why_not"]))
    best, reasons = recommend(judged)
    return {"recommended": best, "reasons": reasons, "garment": garment, "fabric": fabric,
            "method": method + ("+refine" if method == "learned" and refine else ""), "body": draped[0].person.report(),
            "sizes": judged, "notes": draped[0].metrics.get("notes", []), "fit_body_s": fit_s,
            "workers": workers if method == "simulate" else 1,
            "wall_s": time.perf_counter() - t0}, results
