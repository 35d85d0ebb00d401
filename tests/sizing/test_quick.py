"""The service's two-step answer: every size predicted and judged without a simulator,
then only the sizes that decide refined."""

import numpy as np
import pytest

from tryon.body.amortised import quick_fit
from tryon.body.fit import Measurements
from tryon.sizing.quick import first_answer, shipped_model

pytestmark = pytest.mark.anny

PERSON = Measurements(height_cm=180, weight_kg=80, gender="male")


@pytest.fixture(scope="module")
def answered():
    person = quick_fit(PERSON)
    return person, first_answer(person, "male", "tshirt")


def test_every_size_is_predicted_and_judged_by_its_ease(answered):
    _, first = answered
    model = shipped_model("tshirt")
    assert [p.size for p in first.sizes] == model.sizes
    eases = [p.judged["torso_ease_cm"] for p in first.sizes]
    assert np.all(np.diff(eases) > 0), eases  # a larger size stands further off the skin
    assert all(p.judged["judged_on"] == "prediction" for p in first.sizes)
    assert first.recommended in model.sizes and first.reasons[0].startswith(first.recommended)
    for p in first.sizes:
        assert p.x.shape == p.garment.vertices.shape and np.isfinite(p.strain).all()
        assert p.skin_distance.shape == (len(p.x),) and np.median(p.skin_distance) > 0
    # strain is not trusted on a prediction: a size fits or not by its ease alone
    assert all(p.judged["fits"] == (min(r["ease_cm"] for r in p.judged["regions"].values()) >= 0.5)
               for p in first.sizes)


@pytest.mark.slow
def test_refinement_settles_the_predicted_size_and_says_why_the_others_were_not(answered):
    from tryon.drape.pipeline import DrapeRequest
    from tryon.sizing.quick import refine_decisive

    person, first = answered
    seen = []
    best, reasons, judged, refined = refine_decisive([p.judged for p in first.sizes], first.recommended, person,
                                                     DrapeRequest(PERSON, garment="tshirt"),
                                                     on_refined=lambda size, result: seen.append(size))
    assert first.recommended in refined and seen == list(refined)
    assert best in refined and reasons[0].startswith(best)
    for j in judged:
        if j["size"] in refined:
            assert j["judged_on"] == "refined drape" and "not_refined" not in j
        else:
            assert j["judged_on"] == "prediction" and j["not_refined"]
    assert refined[best].metrics["penetration_pct"] == 0.0


def _j(size, fits, ease, on="refined drape"):
    return {"size": size, "fits": fits, "torso_ease_cm": ease, "judged_on": on}


def test_refinement_goes_one_size_up_only_where_the_larger_would_be_the_better_fit():
    from tryon.sizing.judge import TARGET_EASE_CM as T
    from tryon.sizing.quick import _refine_next

    tight_fit = [_j("S", True, 0.6), _j("M", True, T + 0.2, "prediction")]
    assert _refine_next(tight_fit, 0)  # fits, but M is predicted nearer a regular fit
    assert not _refine_next([_j("S", True, 0.6), _j("M", True, T + 3.0, "prediction")], 0)  # M too loose
    assert not _refine_next([_j("S", True, T + 0.1), _j("M", True, T + 1.5, "prediction")], 0)  # S is regular
    assert _refine_next([_j("S", False, -0.5), _j("M", True, 1.0, "prediction")], 0)  # S does not fit
    assert not _refine_next([_j("S", False, -0.5)], 0)  # nothing larger
    # a larger size refined that does not fit where a smaller refined one did: stop there
    assert not _refine_next([_j("S", True, 0.6), _j("M", False, 1.0), _j("L", True, 2.0, "prediction")], 1)


@pytest.mark.slow
def test_a_refinement_for_judging_stops_once_the_verdict_settles_and_agrees_with_one_run_to_rest(answered):
    from tryon.drape.pipeline import DrapeRequest
    from tryon.learn.drape import learned_drape
    from tryon.sizing.judge import judge_size
    from tryon.sizing.quick import refined_for_judging

    person, _ = answered
    request = DrapeRequest(PERSON, garment="tshirt", size="XL", allow_tight=True)  # loose: far from every threshold
    quick = refined_for_judging(request, person, shipped_model("tshirt"))
    rest = learned_drape(request, refine=True, person=person, model=shipped_model("tshirt"))
    assert quick.metrics["refine_steps"] < rest.metrics["refine_steps"]
    a, b = judge_size(request.size, quick), judge_size(request.size, rest)
    assert a["fits"] == b["fits"]
    assert abs(a["torso_ease_cm"] - b["torso_ease_cm"]) < 0.4
    assert abs(a["overstrained_area_pct"] - b["overstrained_area_pct"]) < 1.0
    assert quick.metrics["penetration_pct"] == 0.0
