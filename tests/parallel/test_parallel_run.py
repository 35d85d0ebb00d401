"""Time-parallel runs in the in-process mode: joining segments into the serial run's
frames, the serial output format, checkpoint/resume and bad input."""

import json

import numpy as np
import pytest

from tryon.errors import TryonError
from tryon.parallel import ParallelOptions, run_scene_time_parallel, simulate_time_parallel
from tryon.parallel.join import join_segments
from tryon.sim.runner import run_scene, simulate
from tryon.sim.scene import example_scene


def _scene(duration: float = 0.3):
    return example_scene("sphere-drop", 13, duration=duration)


@pytest.fixture(scope="module")
def serial():
    return simulate(_scene(), progress=False)


@pytest.fixture(scope="module")
def local_run():
    opts = ParallelOptions(workers=3, partition="uniform", mode="local")
    return simulate_time_parallel(_scene(), opts, progress=False)


def test_local_run_joins_into_the_serial_frames(serial, local_run):
    r = local_run
    assert r.positions.shape == serial.positions.shape
    assert np.allclose(r.times, serial.times)
    cuts = r.summary["parallel"]["cuts"]
    assert cuts == [0, 10, 20, 30] and len(r.segments) == 3
    steps = [k for s in r.segments for k in s.own_steps]
    assert steps == sorted(set(steps)) and len(steps) == len(serial.times) - 1
    # segments run past their ends for the cross-fade (all but the last)
    assert [max(s.frame_steps) for s in r.segments] == [20, 30, 30]  # at most the next segment's length
    # segment 0 starts from the exact initial state: its frames are the serial run's
    first = len(r.segments[0].own_steps) + 1
    assert np.allclose(r.positions[:first], serial.positions[:first], atol=1e-9)
    # later segments start from recovered coarse states: close to, not equal to, serial
    assert not np.allclose(r.positions[first:], serial.positions[first:], atol=1e-9)
    assert np.all(np.isfinite(r.positions))
    assert r.summary["intersections"] == 0
    for s in r.segments[1:]:
        assert s.recovery["iterations"] >= 1 and s.x_upsampled is not None
    assert r.summary["parallel"]["K"] > 1.0


def test_join_rejects_lost_or_duplicated_frames(local_run):
    h, segs = local_run.hierarchy, local_run.segments
    with pytest.raises(TryonError, match="missing frames at steps \\[12"):
        join_segments(h, [segs[0], segs[2]])
    with pytest.raises(TryonError, match="duplicated"):
        join_segments(h, [segs[0], segs[1], segs[1], segs[2]])
    positions, times = join_segments(h, segs)
    assert np.array_equal(positions, local_run.positions)


@pytest.mark.parametrize("partition", ["balanced", "adaptive"])
def test_other_partitions_cover_every_step(serial, partition):
    r = simulate_time_parallel(_scene(), ParallelOptions(workers=2, partition=partition, mode="local"), progress=False)
    cuts = r.summary["parallel"]["cuts"]
    assert cuts[0] == 0 and cuts[-1] == 30 and len(cuts) == 3
    assert np.allclose(r.times, serial.times)
    if partition == "adaptive":
        assert r.summary["parallel"]["adaptive_history"][0]["cut"] == cuts[1]
    else:
        assert r.summary["parallel"]["probe"]["K"] > 0


def test_output_files_have_the_serial_format(tmp_path):
    scene = _scene(0.1)
    run_scene(scene, tmp_path / "serial", progress=False)
    run_scene_time_parallel(scene, tmp_path / "par", workers=2, partition="uniform", mode="local", progress=False)
    names = lambda d: sorted(p.relative_to(d).as_posix() for p in d.rglob("*"))  # noqa: E731
    assert names(tmp_path / "par") == names(tmp_path / "serial")
    a, b = np.load(tmp_path / "serial" / "frames.npz"), np.load(tmp_path / "par" / "frames.npz")
    assert sorted(a.files) == sorted(b.files)
    assert a["positions"].shape == b["positions"].shape and np.allclose(a["times"], b["times"])
    summary = json.loads((tmp_path / "par" / "summary.json").read_text())
    for key in ("steps", "wall_s", "s_per_step", "max_strain", "intersections", "min_obstacle_distance"):
        assert key in summary
    assert not (tmp_path / "par.partial").exists()


class _Stop(Exception):
    pass


def test_an_interrupted_run_resumes_with_its_finished_segments(tmp_path):
    scene = _scene(0.3)
    opts = ParallelOptions(workers=3, partition="uniform", mode="local", crossfade=0.05)
    full = simulate_time_parallel(scene, opts, progress=False)

    def stop_late(p):
        if p.index == 2 and p.step == 29:
            raise _Stop()

    with pytest.raises(_Stop):
        run_scene_time_parallel(scene, tmp_path / "out", options=opts, progress=False, on_progress=stop_late)
    saved = sorted(p.name for p in (tmp_path / "out.partial" / "parallel").glob("segment_*.npz"))
    assert saved == ["segment_0000.npz", "segment_0001.npz"]
    again = run_scene_time_parallel(scene, tmp_path / "out", options=opts, progress=False, resume=True)
    assert again.summary["parallel"]["resumed_segments"] == [0, 1]
    assert np.allclose(again.positions, full.positions, atol=1e-9)
    assert (tmp_path / "out" / "frames.npz").exists() and not (tmp_path / "out.partial").exists()


def test_bad_requests_raise_clear_errors():
    scene = _scene(0.05)
    with pytest.raises(TryonError, match="--workers must be at least 1"):
        simulate_time_parallel(scene, ParallelOptions(workers=0, mode="local"), progress=False)
    with pytest.raises(TryonError, match="segments need at least"):
        simulate_time_parallel(scene, ParallelOptions(workers=8, mode="local"), progress=False)
    with pytest.raises(TryonError, match="--coarse-dt-ratio must be a whole number"):
        simulate_time_parallel(scene, ParallelOptions(dt_ratio=0, mode="local"), progress=False)
    with pytest.raises(TryonError, match="unknown partition"):
        simulate_time_parallel(scene, ParallelOptions(partition="random", mode="local"), progress=False)
    with pytest.raises(TryonError, match="no Ray cluster answers"):
        simulate_time_parallel(scene, ParallelOptions(workers=2, ray_address="127.0.0.1:1"), progress=False)


def test_join_cross_fades_each_boundary_from_the_previous_segments_overlap(local_run):
    from tryon.parallel.join import crossfade_weight

    w = [crossfade_weight(k, 10, 8) for k in range(8, 21)]
    assert w[:3] == [0.0, 0.0, 0.0] and w[-3:] == [1.0, 1.0, 1.0] and np.all(np.diff(w) >= 0)
    assert crossfade_weight(14, 10, 8) == pytest.approx(0.5)
    r = local_run
    prev, seg = r.segments[0], r.segments[1]
    frames = dict(zip(r.times.round(6), r.positions))
    blended = 0
    for k, own in zip(seg.frame_steps, seg.frames):
        if k > seg.end:
            break
        joined = frames[round(k * r.hierarchy.fine.dt, 6)]
        if k >= seg.end:  # the overlap is longer than the segment: w reaches 1 at its end
            assert np.array_equal(joined, own)
            continue
        earlier = prev.frames[prev.frame_steps.index(k)]
        wk = crossfade_weight(k, seg.start, seg.end - seg.start)
        assert np.allclose(joined, (1 - wk) * earlier + wk * own, atol=1e-4)  # obstacle push-outs aside
        blended += 1
    assert blended >= 2 and r.summary["parallel"]["crossfade"]["blended_frames"]["10"] == blended


def test_without_crossfade_segments_stop_at_their_ends(serial):
    r = simulate_time_parallel(_scene(), ParallelOptions(workers=3, partition="uniform", mode="local", crossfade=0.0),
                               progress=False)
    assert all(max(s.frame_steps) <= s.end for s in r.segments)
    own = np.concatenate([s.frames for s in r.segments])
    assert np.array_equal(r.positions[1:], own) and r.summary["parallel"]["crossfade"]["steps"] == 0
    with pytest.raises(TryonError, match="--crossfade must be a duration"):
        simulate_time_parallel(_scene(), ParallelOptions(crossfade=-1.0, mode="local"), progress=False)


def test_bench_popping_measures_the_jump_the_plain_join_shows(local_run):
    """With the serial states in place of the joined frames, the cross-faded pop is zero,
    while the plain join's pop (from the segments' own frames) stays what it was."""
    from tryon.bench.parallel import popping, serial_run

    states, _ = serial_run(_scene())
    r = local_run
    measured = popping(r, states)
    assert measured["pop_plain_mm"] > 0 and np.isfinite(measured["pop_crossfade_mm"])
    assert measured["serial_frame_mm"] > 0
    steps = [0] + [k for s in r.segments for k in s.own_steps]

    class _Serial:
        hierarchy, segments, summary = r.hierarchy, r.segments, r.summary
        positions = states[steps]

    ideal = popping(_Serial(), states)
    assert ideal["pop_crossfade_mm"] == 0.0 and ideal["pop_plain_mm"] == measured["pop_plain_mm"]


def test_segments_starting_through_themselves_restart_from_their_predecessor(serial, local_run, monkeypatch):
    """A recovered start that crosses itself cannot be stepped out of: the segment is run
    again from the state its predecessor reached at the boundary. With every recovered
    start refused, the joined run is the serial run, frame for frame."""
    import tryon.parallel.segment as segment

    refused = []

    def crossing_start(hier, x, t):  # every recovered start (t > 0) crosses; the scene's own start does not
        if t == 0.0:
            return 0
        refused.append(round(t, 6))
        return 7

    monkeypatch.setattr(segment, "start_crossings", crossing_start)
    opts = ParallelOptions(workers=3, partition="uniform", mode="local")
    r = simulate_time_parallel(_scene(), opts, progress=False)
    par = r.summary["parallel"]
    assert par["restarted_segments"] == {"1": {"start_crossings": 7}, "2": {"start_crossings": 7}}
    assert len(refused) == 2  # a restart starts from the exact state and is not checked again
    assert [s.restarted for s in r.segments] == [0, 7, 7]
    assert all(s.x_upsampled is None and s.start_crossings == 0 for s in r.segments[1:])
    assert r.summary["intersections"] == 0
    # the same states at every boundary: the joined run follows the serial one (a fresh
    # solver's warm start differs at round-off, which the dropping cloth grows to millimetres)
    # (sphere-drop is chaotic: 7 um after the first boundary grow to centimetres by the end)
    dev = np.abs(r.positions - serial.positions).max(axis=(1, 2))
    recovered = np.abs(local_run.positions - serial.positions).max(axis=(1, 2))
    first = len(r.segments[0].own_steps) + 1  # the first frame after the first boundary
    assert np.all(dev[:first] < 1e-9)
    assert dev[first] < 1e-4 and recovered[first] > 3e-4, (dev[first], recovered[first])


def test_a_blend_that_stays_through_the_obstacle_is_replaced_by_the_later_frame(local_run, monkeypatch):
    import tryon.parallel.join as join

    hier, prev, seg = local_run.hierarchy, local_run.segments[0], local_run.segments[1]
    k = seg.frame_steps[0]  # the first frame after the boundary, which the previous segment also ran to
    earlier, later = prev.frames[prev.frame_steps.index(k)], seg.frames[0]
    x, replaced = join._blend(hier, earlier, later, 0.5, k * hier.fine.dt)
    assert not replaced and np.allclose(x, 0.5 * (earlier + later))
    # a blend that pushing out cannot clear, where the simulated frame is clear
    monkeypatch.setattr(join, "obstacle_crossings", lambda h, y, t: int(not np.array_equal(y, later)))
    monkeypatch.setattr(join, "push_outside", lambda h, y, t: y)
    x, replaced = join._blend(hier, earlier, later, 0.5, 0.0)
    assert replaced and x is later


def test_the_bench_serial_baseline_runs_on_one_workers_threads():
    import numba
    import torch

    from tryon.parallel.executors import worker_threads

    outer = torch.get_num_threads(), numba.get_num_threads()
    # two threads before, whatever the test process runs on (one per test worker), so that
    # the restore is seen (numba: as many as it was started with allow)
    torch.set_num_threads(2)
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    before = torch.get_num_threads(), numba.get_num_threads()
    try:
        with worker_threads():
            assert (torch.get_num_threads(), numba.get_num_threads()) == (1, 1)
        assert (torch.get_num_threads(), numba.get_num_threads()) == before
        with pytest.raises(RuntimeError), worker_threads():
            raise RuntimeError("a failing baseline")
        assert (torch.get_num_threads(), numba.get_num_threads()) == before
    finally:
        torch.set_num_threads(outer[0])
        numba.set_num_threads(outer[1])


def test_bench_twin_starts_a_micrometre_away_and_measures_its_spread(local_run):
    """The serial run's twin starts from positions moved by ~1 um (pinned vertices stay on
    their handles); boundary errors against the serial run itself as the twin are zero."""
    from tryon.bench.parallel import SPREAD_PERTURBATION, boundary_errors, serial_run

    hanging = example_scene("hanging", 6, duration=0.05)
    states, _ = serial_run(hanging)
    twin, _ = serial_run(hanging, perturb=SPREAD_PERTURBATION)
    pinned = hanging.model.pinned.numpy()
    moved = np.linalg.norm(twin[0] - states[0], axis=1)
    assert len(pinned) and np.all(moved[pinned] == 0.0)
    free = np.setdiff1d(np.arange(len(moved)), pinned)
    assert 0.2e-6 < np.median(moved[free]) < 5e-6
    serial_states, _ = serial_run(_scene())
    errors = boundary_errors(local_run.hierarchy, local_run.segments, serial_states, twin=serial_states)
    assert errors and all(e["serial_spread"] == 0.0 and e["serial_spread_mm"] == 0.0 for e in errors)
