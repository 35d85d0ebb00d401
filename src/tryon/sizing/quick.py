"""The service's answer in two steps (`tryon serve`).

1. `first_answer`: every size predicted by the learned model and judged on its prediction
   (by ease: a prediction's strain is noise until refined). No simulator model is built,
   so every size of a garment is predicted and judged in a fraction of a second on one
   thread.
2. `refine_decisive`: only the sizes that decide are refined by the simulator: the
   predicted recommendation, then the next larger while the refined one does not fit.
   A smaller size is tighter everywhere, so once a size fits none below it would fit
   looser; the sizes not refined keep their prediction's numbers and are not candidates.

`tryon size` refines more thoroughly (`tryon.sizing.recommend`); both judge and recommend
with `tryon.sizing.judge`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from tryon.body.fit import BodyFit
from tryon.body.measure import drafting_measurements
from tryon.body.pose import BodyPose, posed_body
from tryon.drape.pipeline import DrapeRequest, DrapeResult
from tryon.garment.sizes import SIZES
from tryon.sizing.judge import MAX_OVERSTRAINED_PCT, MIN_EASE_CM, ease_of, judge, judge_size, recommend, target_of


@dataclass
class PredictedSize:
    """One size predicted on the person: the garment (rest shape, panels), its vertices,
    strain per face, distance to the skin per vertex (m) and its judgement."""

    size: str
    garment: object
    x: np.ndarray
    strain: np.ndarray
    skin_distance: np.ndarray
    judged: dict


@dataclass
class FirstAnswer:
    recommended: str
    reasons: list[str]
    sizes: list[PredictedSize]
    body: BodyPose  # the A-posed body the sizes were predicted on
    notes: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)


@lru_cache(maxsize=8)
def shipped_model(garment: str):
    """The garment's shipped learned model, loaded once per process."""
    from tryon.learn.model import load_shipped

    return load_shipped(garment)


def ordered_sizes(sizes) -> list[str]:
    return sorted({s.upper() for s in sizes}, key=lambda s: SIZES.index(s) if s in SIZES else 99)


def a_posed(person: BodyFit) -> BodyPose:
    """The body the learned model and the refinement drape on."""
    return posed_body(person.shape, "a", drafting_measurements(person.shape)["crotch_height"])


def garment_strain(garment, x: np.ndarray) -> np.ndarray:
    """The largest principal stretch - 1 of each face of `garment` at positions `x`."""
    import torch

    from tryon.sim.forces.geometry import rest_state
    from tryon.sim.metrics import principal_stretch

    faces = torch.from_numpy(garment.faces)
    F = len(garment.faces)
    dm_inv, _ = rest_state(torch.from_numpy(garment.corner_uv.reshape(-1, 2)), torch.arange(3 * F).reshape(F, 3))
    return (principal_stretch(torch.from_numpy(np.ascontiguousarray(x)), faces, dm_inv) - 1.0).numpy()


class VerdictSettled:
    """An observer of a refinement (`tryon.sim.loop`) that ends it once the size's verdict
    has settled: from step `first` on, every `every` steps, the size is judged on the
    current drape. Two judgements in a row end the run when they agree on whether it fits,
    on the deciding ease (the torso's, or a skirt's or trousers' hip band's) within `ease_cm` and on the overstretched area within `area_pct`,
    and when no number the verdict hangs on (each region's ease, the overstretched area)
    drifting on at its latest rate until step `horizon` (the refinement's last) would
    cross its threshold; at step `limit` the run ends in any case (a verdict near its
    threshold is then judged as it stands). The garment need not be at rest for that
    (docs/SERVICE.md compares these verdicts with those of runs to rest)."""

    def __init__(self, size: str, garment, body: BodyPose, first: int = 6, every: int = 4, ease_cm: float = 0.1,
                 area_pct: float = 0.5, horizon: int = 60, limit: int = 30):
        self.size, self.garment, self.body = size, garment, body
        self.first, self.every, self.ease_cm, self.area_pct, self.horizon = first, every, ease_cm, area_pct, horizon
        self.limit = limit
        self.last: dict | None = None
        self.settled_at: int | None = None

    def __call__(self, rec) -> bool:
        from tryon.sim.geometry import nearest_surface_points

        if rec.step >= self.limit:  # judged as it stands: a verdict near a threshold waits no longer
            return True
        if rec.step < self.first or (rec.step - self.first) % self.every:
            return False
        x = rec.state.x.numpy()
        d, _, _ = nearest_surface_points(x, self.body.vertices, self.body.faces)
        now = judge(self.size, self.garment, d, garment_strain(self.garment, x), None)
        before, self.last = self.last, now
        if before is None or before["fits"] != now["fits"] or not self._close(before, now):
            return False
        if not self._stays(before, now, rec.step):
            return False
        self.settled_at = rec.step
        return True

    def _close(self, before: dict, now: dict) -> bool:
        a, b = ease_of(now), ease_of(before)  # NaN for a garment with no torso panels or hip band
        ease_close = (np.isnan(a) and np.isnan(b)) or abs(a - b) < self.ease_cm
        return ease_close and abs(now["overstrained_area_pct"] - before["overstrained_area_pct"]) < self.area_pct

    def _stays(self, before: dict, now: dict, step: int) -> bool:
        """No thresholded number crosses its threshold by the horizon at its latest drift."""
        steps_left = max(0, self.horizon - step) / self.every
        pairs = [(before["overstrained_area_pct"], now["overstrained_area_pct"], MAX_OVERSTRAINED_PCT)]
        pairs += [(before["regions"][r]["ease_cm"], now["regions"][r]["ease_cm"], MIN_EASE_CM) for r in now["regions"]]
        for old, new, threshold in pairs:
            reach = new + (new - old) * steps_left
            if (new - threshold) * (reach - threshold) <= 0.0:
                return False
        return True


def refined_for_judging(request: DrapeRequest, person: BodyFit, model) -> DrapeResult:
    """The learned drape of `request`, refined until its verdict settles (`VerdictSettled`)
    rather than until the garment is at rest: what `tryon size` and the service judge."""
    from tryon.learn.drape import learned_drape

    return learned_drape(request, refine=True, person=person, model=model,
                         refine_until=lambda garment, body: VerdictSettled(request.size, garment, body))


def predict_size(model, body: BodyPose, gender: str, size: str, fabric=None) -> PredictedSize:
    from tryon.sim.geometry import nearest_surface_points

    garment = model.reference_garment(gender, size)
    x = model.predict_vertices(body.vertices, gender, size, fabric)
    strain = garment_strain(garment, x)
    d, _, _ = nearest_surface_points(x, body.vertices, body.faces)
    judged = dict(judge(size, garment, d, strain, None, strain_reliable=False), judged_on="prediction")
    return PredictedSize(size, garment, x, strain, d, judged)


def first_answer(person: BodyFit, gender: str, garment: str, sizes: list[str] | None = None,
                 model=None, fabric=None) -> FirstAnswer:
    """Every size (default: every size the model knows) predicted on `person` in `fabric`
    (a Fabric) and judged; the recommendation among them."""
    t0 = time.perf_counter()
    model = model or shipped_model(garment)
    body = a_posed(person)
    t1 = time.perf_counter()
    predicted = [predict_size(model, body, gender, s, fabric) for s in ordered_sizes(sizes or model.sizes)]
    best, reasons = recommend([p.judged for p in predicted])
    notes = model.coverage_notes(gender, person.achieved["height_cm"], person.achieved["bmi"], fabric)
    return FirstAnswer(best, reasons, predicted, body, notes,
                       {"pose_s": t1 - t0, "predict_s": time.perf_counter() - t1})


def _refine_next(judged: list[dict], k: int) -> bool:
    """Whether the size after `k` (just refined) must be refined too."""
    if k + 1 >= len(judged):
        return False
    if not judged[k]["fits"]:
        return not any(j["fits"] for j in judged[:k] if j.get("judged_on") == "refined drape")
    ease, larger, target = ease_of(judged[k]), ease_of(judged[k + 1]), target_of(judged[k])
    return ease < target and abs(larger - target) < abs(ease - target)


def refine_decisive(predicted: list[dict], recommended: str, person: BodyFit, request: DrapeRequest, model=None,
                    on_refined=None) -> tuple[str, list[str], list[dict], dict[str, DrapeResult]]:
    """Refine the predicted recommendation, then each larger size while the refined one
    does not fit, or fits with less ease than a regular fit and the larger size's
    prediction comes closer to it (what `recommend` would choose among them).
    `predicted`: each size's judgement of the first answer (smallest first), `recommended`
    its recommendation. Returns
    (recommended, reasons, every size's judgement, the refined drapes by size).
    `request`: the body, garment and fabric (its size is ignored). `on_refined(size,
    result)` is called as each refined drape is judged."""
    from dataclasses import replace

    model = model or shipped_model(request.garment)
    judged = [dict(j) for j in predicted]
    names = [j["size"] for j in judged]
    refined: dict[str, DrapeResult] = {}
    k = names.index(recommended)
    while k < len(names):
        req = replace(request, size=names[k], allow_tight=True)
        result = refined_for_judging(req, person, model)
        judged[k] = dict(judge_size(names[k], result), judged_on="refined drape")
        refined[names[k]] = result
        if on_refined is not None:
            on_refined(names[k], result)
        if not _refine_next(judged, k):
            break
        k += 1
    lowest, highest = min(refined, key=names.index), max(refined, key=names.index)
    for i, j in enumerate(judged):
        if names[i] in refined:
            continue
        above = [n for n in refined if names.index(n) > i]
        nearest = min(above, key=names.index) if above else None
        if nearest is not None and not judged[names.index(nearest)]["fits"]:  # tighter than a size that does not fit
            j["not_refined"] = f"smaller than {nearest}, which does not fit"
            j.update(fits=False, why_not=j["why_not"] or [f"it is smaller than {nearest}, which does not fit"])
        elif i < names.index(lowest):
            j["not_refined"] = f"smaller than {lowest}, which the prediction chose and which fits"
        else:
            below = [n for n in refined if names.index(n) < i and judged[names.index(n)]["fits"]]
            fitting = max(below, key=names.index) if below else highest
            j["not_refined"] = f"larger than {fitting}, which fits"
    best, reasons = recommend(judged)
    return best, reasons, judged, refined
