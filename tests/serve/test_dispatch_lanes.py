"""The dispatcher's lanes account for every job when workers fail, whatever state each
job's future is in (no worker processes here: futures are set by hand)."""

from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool

from tryon.serve.dispatch import Lane
from tryon.serve.store import Store

BODY = {"height_cm": 172, "weight_kg": 70, "gender": "male"}
REQUEST = {"garment": "tshirt", "fabric": "gray-interlock", "sizes": None}


class HandWorkers:
    """Workers whose jobs end when the test says."""

    def __init__(self, workers: int, fail_submit: bool = False):
        self.workers, self.fail_submit, self.futures, self.restarts = workers, fail_submit, [], 0

    def submit(self, *args) -> Future:
        if self.fail_submit:
            raise OSError("the cluster is gone")
        self.futures.append(Future())
        return self.futures[-1]

    def stop(self, futures) -> bool:  # as a local pool: stopping some replaces the pool
        self.restart()
        return True

    def forget(self, fut) -> None:
        pass

    def restart(self) -> None:
        self.restarts += 1

    def close(self) -> None:
        pass


def _lane(tmp_path, workers):
    store = Store(tmp_path / "tryon.sqlite")
    body_id = store.add_body(BODY, {})
    fits = [store.add_fit(body_id, REQUEST) for _ in range(2)]
    events = {"worker_restarts": 0, "timeouts": 0, "requeued": 0}
    return store, fits, Lane("answer", ("answer",), workers, store, tmp_path, 60.0, events)


def test_a_broken_pool_requeues_every_job_it_held_even_those_already_failed(tmp_path):
    workers = HandWorkers(2)
    store, fits, lane = _lane(tmp_path, workers)
    lane.fill()
    assert len(lane.running) == 2 and store.counts() == {"running": 2}
    workers.futures[0].set_exception(BrokenProcessPool("a worker died"))
    workers.futures[1].set_exception(BrokenProcessPool("a worker died"))
    lane.collect()
    assert workers.restarts == 1 and lane.running == {}
    assert store.claimed() == [] and store.counts() == {"queued": 2}
    assert {store.fit(f).attempts for f in fits} == {1}


def test_restart_keeps_what_finished_and_requeues_the_rest(tmp_path):
    workers = HandWorkers(2)
    store, fits, lane = _lane(tmp_path, workers)
    lane.fill()
    store.update(fits[0], "predicted", 0.3, result={})  # the first finished on its own
    store.next_phase(fits[0], "refine")
    workers.futures[0].set_result("predicted")
    workers.futures[1].set_exception(BrokenProcessPool("a worker died"))  # failed before collect saw it
    lane.restart()
    assert store.fit(fits[0]).status == "predicted" and store.fit(fits[0]).phase == "refine"
    assert store.fit(fits[1]).status == "queued" and not store.fit(fits[1]).claimed


def test_a_failed_hand_over_leaves_the_job_claimable_with_its_tries(tmp_path):
    workers = HandWorkers(1, fail_submit=True)
    store, fits, lane = _lane(tmp_path, workers)
    lane.fill()
    assert lane.running == {} and workers.restarts == 1
    assert store.claimed() == [] and store.fit(fits[0]).attempts == 0


def test_an_orphaned_claim_is_swept_back(tmp_path):
    store, fits, lane = _lane(tmp_path, HandWorkers(1))
    assert store.claim_next(("answer",)) == (fits[0], "answer")  # claimed, never handed to a worker
    lane.fill()  # the lane takes the other one
    assert lane.sweep() == 1
    assert {f for f, _ in store.claimed()} == {fits[1]} and store.fit(fits[0]).status == "queued"
