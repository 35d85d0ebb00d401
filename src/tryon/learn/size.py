"""`tryon size`: which size of a garment fits a person.

Every size the learned model knows is draped on the person (learned + refinement, or
simulated with `method="simulate"`), and each garment region (its pattern panels) is
scored by ease (mean distance from the skin, cm), strain (area-weighted mean, and the
share of area stretched beyond `OVERSTRAIN`) and contact pressure. A size fits when less
than `MAX_OVERSTRAINED_PCT` of its area is overstretched and no region clings tighter
than `MIN_EASE_CM`; among the sizes that fit, the one whose torso ease is nearest
`TARGET_EASE_CM` (a regular fit) is recommended. If none fits, the largest is named, with
the reason. Writes `size.json` (key `recommended`, the reasons and every size's numbers)
and `sizes.png` (each size's strain map, front and back).

Refinement is the slow part, and slowest on a size far too small (the simulator fights
the strain). A smaller size is tighter everywhere, so the learned path refines from the
largest size down and stops as soon as the answer is settled: at a size that does not fit
(every smaller one is tighter still) or at one that fits closer than a regular fit (every
smaller one is farther from it). Sizes below the stop keep their prediction's numbers,
marked `"judged_on": "prediction"`, and are not candidates."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from tryon.body.fit import Measurements, fit_body
from tryon.drape.pipeline import DrapeRequest, DrapeResult
from tryon.errors import TryonError
from tryon.garment.drafts import Ease

OVERSTRAIN = 0.10
MAX_OVERSTRAINED_PCT = 10.0
MIN_EASE_CM = 0.5
# A regular fit: the draft's own chest ease (10 cm of girth) spread round the body, about
# 1.6 cm off the skin; the fit a size has on the body it was drafted for.
TARGET_EASE_CM = 100.0 * Ease().chest / (2.0 * math.pi)
TORSO = ("front", "back")


def region_scores(result: DrapeResult) -> dict[str, dict[str, float]]:
    """Per panel: ease (cm), mean strain (%), overstrained area (%), mean contact pressure (kPa)."""
    from tryon.sim.collision import nearest_surface_points

    g = result.garment
    names = [p.name for p in g.pattern.panels]
    d, _, _ = nearest_surface_points(result.x, result.body_vertices, result.body_faces)
    e1, e2 = g.corner_uv[:, 1] - g.corner_uv[:, 0], g.corner_uv[:, 2] - g.corner_uv[:, 0]
    area = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) / 2  # rest area of each face (m^2)
    out = {}
    for k, name in enumerate(names):
        f = g.face_panel == k
        v = np.unique(g.faces[f])
        a = area[f]
        out[name] = {"ease_cm": float(100 * d[v].mean()), "mean_strain_pct": float(100 * (result.strain[f] * a).sum() / a.sum()),
                     "overstrained_area_pct": float(100 * a[result.strain[f] > OVERSTRAIN].sum() / a.sum()),
                     "mean_pressure_kpa": float(result.pressure[v].mean() / 1000.0)}
    return out


def judge_size(size: str, result: DrapeResult, strain_reliable: bool = True) -> dict:
    """Whether `size` fits, from its drape. A network's prediction (`strain_reliable`
    False) is judged by its ease alone: millimetres of noise in its vertices read as several
    % of strain, so its overstretched area says nothing until refinement."""
    regions = region_scores(result)
    torso = [regions[r] for r in TORSO if r in regions]
    ease = float(np.mean([r["ease_cm"] for r in torso])) if torso else float("nan")
    over = float(result.metrics["overstrained_area_pct"])
    tight = [name for name, r in regions.items() if r["ease_cm"] < MIN_EASE_CM]
    why = []
    if strain_reliable and over >= MAX_OVERSTRAINED_PCT:
        why.append(f"{over:.0f} % of its area is stretched beyond {100 * OVERSTRAIN:.0f} %")
    if tight:
        why.append(f"it clings to the skin at the {', '.join(tight)} (ease under {MIN_EASE_CM} cm)")
    return {"size": size, "fits": not why, "why_not": why, "torso_ease_cm": ease, "overstrained_area_pct": over,
            "max_strain_pct": 100 * float(result.metrics["max_strain"]), "penetration_pct": float(result.metrics["penetration_pct"]),
            "regions": regions, "timings": result.timings}


def recommend(judged: list[dict]) -> tuple[str, list[str]]:
    """(the recommended size, the reasons). Sizes judged on the refined or simulated drape
    are the candidates; sizes judged on a prediction only count when nothing was refined."""
    settled = [j for j in judged if j.get("judged_on") != "prediction"] or judged
    fitting = [j for j in settled if j["fits"]]
    if not fitting:
        last = settled[-1]
        return last["size"], [f"no size fits: even {last['size']} does not, since " + "; ".join(last["why_not"])]
    best = min(fitting, key=lambda j: abs(j["torso_ease_cm"] - TARGET_EASE_CM))
    stretch = ("strain judged after refinement" if best.get("judged_on") == "prediction"
               else f"{best['overstrained_area_pct']:.0f} % of the area overstretched")
    reasons = [f"{best['size']}: torso ease {best['torso_ease_cm']:.1f} cm (a regular fit is about {TARGET_EASE_CM:.1f} cm), "
               f"{stretch}"]
    for j in judged:
        if j is best:
            continue
        if j.get("not_refined"):  # predicted only, below where refinement stopped
            verdict = "does not fit (" + "; ".join(j["why_not"]) + ")" if j["why_not"] else "fits"
            reasons.append(f"{j['size']} was not refined ({j['not_refined']}); its prediction {verdict}, "
                           f"torso ease {j['torso_ease_cm']:.1f} cm")
        elif j["fits"]:
            reasons.append(f"{j['size']} also fits, {'looser' if j['torso_ease_cm'] > best['torso_ease_cm'] else 'closer'}: "
                           f"torso ease {j['torso_ease_cm']:.1f} cm")
        else:
            reasons.append(f"{j['size']} does not fit: " + "; ".join(j["why_not"]))
    return best["size"], reasons


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

    def predicted(req: DrapeRequest) -> tuple[DrapeResult, dict]:
        r = learned_drape(req, person=person, model=model)
        return r, dict(judge_size(req.size, r, strain_reliable=False), judged_on="prediction")

    if not refine:
        pairs = [predicted(req) for req in requests]
        return [r for r, _ in pairs], [j for _, j in pairs]
    results, judged = [None] * len(requests), [None] * len(requests)
    for k in reversed(range(len(requests))):
        results[k] = learned_drape(requests[k], refine=True, person=person, model=model)
        judged[k] = dict(judge_size(requests[k].size, results[k]), judged_on="refined drape")
        size = judged[k]["size"]
        if not judged[k]["fits"]:
            why = f"smaller than {size}, which does not fit"
        elif judged[k]["torso_ease_cm"] <= TARGET_EASE_CM:
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


def undrapeable(size: str, reason: str) -> dict:
    """The judgement of a size the simulator could not drape on the body."""
    nan = float("nan")
    return {"size": size, "fits": False, "why_not": [f"the simulator could not drape it ({reason.split(';')[0]})"],
            "torso_ease_cm": nan, "overstrained_area_pct": nan, "max_strain_pct": nan, "penetration_pct": nan,
            "regions": {}, "timings": {}}


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
        judged = [undrapeable(s, r) if isinstance(r, str) else dict(judge_size(s, r), judged_on="simulated drape")
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


def sizes_picture(results: list[DrapeResult | str], judged: list[dict], recommended: str) -> np.ndarray:
    """Each size's strain map (front and back), labelled, side by side."""
    from PIL import Image, ImageDraw, ImageFont

    from tryon.drape.outputs import fit_map_image

    try:
        font = ImageFont.load_default(size=26)
    except TypeError:  # Pillow before 10.1: the fixed bitmap font
        font = ImageFont.load_default()
    tiles = []
    for r, j in zip(results, judged):
        if isinstance(r, str):  # a size the simulator could not drape
            continue
        img = fit_map_image(r.body_vertices, r.body_faces, r.x, r.garment.faces, 100.0 * r.strain, vmax=20.0, label="strain %")
        pil = Image.fromarray(img[..., :3])
        mark = " (recommended)" if j["size"] == recommended else ("" if j["fits"] else " (does not fit)")
        if "not_refined" in j:
            mark += " (predicted)"
        ImageDraw.Draw(pil).text((12, 12), f"size {j['size']}{mark}: torso ease {j['torso_ease_cm']:.1f} cm", fill=(0, 0, 0), font=font)
        tiles.append(np.asarray(pil))
    h = max(t.shape[0] for t in tiles)
    tiles = [np.pad(t, ((0, h - t.shape[0]), (0, 0), (0, 0)), constant_values=255) for t in tiles]
    return np.concatenate(tiles, axis=1)


def write_size_outputs(rec: dict, results: list[DrapeResult | str], out: str | Path, force: bool = False) -> Path:
    from tryon.io.atomic import atomic_output_dir
    from tryon.io.json_safe import dumps_json
    from tryon.render.offscreen import save_png

    with atomic_output_dir(out, force=force) as tmp:
        (tmp / "size.json").write_text(dumps_json(rec, indent=1))
        save_png(tmp / "sizes.png", sizes_picture(results, rec["sizes"], rec["recommended"]))
    return Path(out)
