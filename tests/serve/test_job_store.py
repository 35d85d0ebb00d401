"""The service's job store: a fit's phases, claims, and what a cut-off phase becomes."""

from tryon.serve.store import MAX_ATTEMPTS, Store

BODY = {"height_cm": 172, "weight_kg": 70, "gender": "male"}
REQUEST = {"garment": "tshirt", "fabric": "gray-interlock", "sizes": None}


def _fit(tmp_path, phase="answer"):
    store = Store(tmp_path / "tryon.sqlite")
    body_id = store.add_body(BODY, {"measurements": {}})
    return store, store.add_fit(body_id, REQUEST, phase)


def test_a_learned_fit_is_answered_then_refined_by_different_lanes(tmp_path):
    store, fit_id = _fit(tmp_path)
    assert store.claim_next(("refine", "simulate")) is None  # the work lane waits for the answer
    assert store.claim_next(("answer",)) == (fit_id, "answer")
    assert store.fit(fit_id).status == "running" and store.claim_next(("answer",)) is None  # claimed once
    store.update(fit_id, "predicted", 0.3, result={"recommended": "M"})
    store.next_phase(fit_id, "refine")
    row = store.fit(fit_id)
    assert (row.status, row.phase, row.claimed, row.attempts) == ("predicted", "refine", False, 0)
    assert store.claim_next(("answer",)) is None
    assert store.claim_next(("refine", "simulate")) == (fit_id, "refine")
    assert store.fit(fit_id).status == "predicted"  # a shopper still sees the prediction while it refines
    store.update(fit_id, "refined", 1.0, result={"recommended": "L"})
    assert store.waiting() == 0 and store.fit(fit_id).result == {"recommended": "L"}


def test_a_cut_off_refinement_keeps_the_prediction_and_runs_again_then_fails(tmp_path):
    store, fit_id = _fit(tmp_path)
    store.claim_next(("answer",))
    store.update(fit_id, "predicted", 0.3, result={"recommended": "M"})
    store.next_phase(fit_id, "refine")
    for _ in range(MAX_ATTEMPTS - 1):
        assert store.claim_next(("refine",)) == (fit_id, "refine")
        assert store.recover() == {"predicted": 1}  # a restart finds it claimed: claimable again
    assert store.claim_next(("refine",)) == (fit_id, "refine")
    assert store.requeue_or_fail(fit_id, "a worker process died") == "failed"
    row = store.fit(fit_id)
    assert row.status == "failed" and "died" in row.reason and row.result == {"recommended": "M"}


def test_a_cut_off_first_answer_is_queued_again(tmp_path):
    store, fit_id = _fit(tmp_path, "simulate")
    assert store.claim_next(("answer",)) is None
    assert store.claim_next(("refine", "simulate")) == (fit_id, "simulate")
    assert store.requeue_or_fail(fit_id, "a worker process died") == "queued"
    assert store.claim_next(("refine", "simulate")) == (fit_id, "simulate")


def test_pruning_forgets_old_finished_fits_and_unused_bodies(tmp_path):
    store, fit_id = _fit(tmp_path)
    spare = store.add_body(BODY, {"measurements": {}})
    assert store.prune(-1.0) == ([], [spare])  # the fit's body stays while the fit is live
    store.update(fit_id, "failed", 1.0, reason="x")
    fits, bodies = store.prune(-1.0)
    assert fits == [fit_id] and len(bodies) == 1 and store.fit(fit_id) is None


def test_a_phase_that_moved_on_is_never_released_by_a_late_requeue(tmp_path):
    store, fit_id = _fit(tmp_path)
    store.claim_next(("answer",))
    store.update(fit_id, "predicted", 0.3, result={"recommended": "M"})
    store.next_phase(fit_id, "refine")  # the answer worker finished, then its process died
    assert store.claim_next(("refine",)) == (fit_id, "refine")
    assert store.requeue_or_fail(fit_id, "a worker process died", "answer") == "predicted"
    row = store.fit(fit_id)
    assert row.claimed and row.phase == "refine"  # still the refining worker's
    assert store.claim_next(("refine",)) is None  # never claimed twice


def test_a_phase_cut_off_for_another_jobs_trouble_keeps_its_tries(tmp_path):
    store, fit_id = _fit(tmp_path)
    for _ in range(MAX_ATTEMPTS + 2):
        assert store.claim_next(("answer",)) == (fit_id, "answer")
        assert store.requeue_or_fail(fit_id, "its worker pool was replaced", "answer", charge=False) == "queued"
    assert store.fit(fit_id).attempts == 0
    assert store.claimed() == []
