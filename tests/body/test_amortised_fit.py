"""The amortised body fit: the shipped network's quick fit lands where the full fit does."""

import numpy as np
import pytest

from tryon.body.amortised import (FEATURE_TAPES, AmortisedFit, person_features, quick_fit, shipped_amortised)
from tryon.body.fit import Measurements, fit_body
from tryon.io.threads import one_torch_thread

pytestmark = pytest.mark.anny

# across the supported range: typed girths, the photos' eight tapes, nothing but stature and weight
PEOPLE = [
    Measurements(height_cm=152, weight_kg=44, gender="female", age=22),
    Measurements(height_cm=198, weight_kg=150, gender="male", age=55),
    Measurements(height_cm=165, weight_kg=60, gender="female", chest_cm=92, waist_cm=72, hip_cm=100),
    Measurements(height_cm=180, weight_kg=82, gender="male", age=35, chest_cm=104, waist_navel_cm=90, hip_cm=102,
                 neck_cm=40, thigh_cm=58, shoulder_width_cm=42, arm_length_cm=60, crotch_height_cm=84),
    Measurements(height_cm=162, weight_kg=95, gender="female", age=70),
]


def test_the_features_say_what_was_given():
    x = person_features(PEOPLE[2])
    flags = dict(zip(FEATURE_TAPES, x[5::2]))
    assert flags["chest"] == flags["waist"] == flags["hip"] == 1.0 and flags["neck"] == 0.0
    assert x[4 + 2 * FEATURE_TAPES.index("chest")] == pytest.approx(0.92)


@pytest.mark.parametrize("person", PEOPLE, ids=["small", "large", "girths", "photo-tapes", "older"])
def test_the_quick_fit_lands_within_half_a_centimetre_of_the_full_fit(person):
    assert shipped_amortised() is not None, "the amortised network ships with tryon"
    with one_torch_thread():
        full = fit_body(person)
        quick = quick_fit(person)
    asked = {"height_cm"} | {f"{k}_cm" for k in person.tapes()}
    diff = {k: abs(quick.achieved[k] - full.achieved[k]) for k in asked | {"chest_cm", "waist_cm", "hip_cm"}}
    assert max(diff[k] for k in asked) <= 0.5, diff  # the measure: stature and every girth asked
    assert max(diff.values()) <= 1.0, diff             # and the girths the prior chose, near enough to size by
    assert quick.iterations < full.iterations


def test_a_network_for_other_body_controls_is_ignored(tmp_path):
    net = shipped_amortised()
    stale = AmortisedFit(net.weights, net.biases, net.x_mean, net.x_sd, net.z_mean, net.z_sd,
                         {**net.card, "local_changes": ["a-control-anny-no-longer-has"]})
    stale.save(tmp_path / "stale.npz")
    assert shipped_amortised(tmp_path / "stale.npz") is None
    # and with no network the quick fit is the full one
    person = PEOPLE[0]
    with one_torch_thread():
        assert quick_fit(person, net=None).achieved["height_cm"] == pytest.approx(person.height_cm, abs=1.0)


@pytest.mark.slow
def test_a_tiny_training_run_makes_a_network_that_predicts_the_unknowns(tmp_path, monkeypatch):
    import tryon.body.amortised_build as build

    monkeypatch.setattr(build, "CHUNK", 10)
    monkeypatch.setattr(build, "TEST_EVERY", 5)
    build.build(tmp_path / "fits", 20, seed=3, progress=False)
    assert sorted(p.name for p in (tmp_path / "fits").iterdir()) == ["fits-000000.npz", "fits-000010.npz"]
    model = build.train(tmp_path / "fits", tmp_path / "net.npz", epochs=300, hidden=32, check=1, progress=False)
    assert (tmp_path / "net.md").exists() and model.card["people"] == {"train": 16, "test": 4}
    again = AmortisedFit.load(tmp_path / "net.npz")
    x = person_features(build.draw_person(3, 0))
    assert np.allclose(again.predict(x), model.predict(x))
    z = np.concatenate([np.load(p)["z"] for p in sorted((tmp_path / "fits").iterdir())])
    assert model.card["unknowns_rms"]["train"] < 0.5 * np.sqrt(z.var(0).mean())  # better than the mean person
