"""Dataset folders: manifests, shards that are never rewritten, resume, body sampling."""

import json

import numpy as np
import pytest

from tryon.dataset import BodyRanges, DatasetError, Manifest, ShardStore, open_dataset, run_generator
from tryon.dataset.bodies import draw_measurements
from tryon.errors import TryonError
from tryon.io.atomic import OutputFolderError


def _manifest(count=10, shard_size=4, seed=1, spec=None):
    return Manifest("toy", 1, "test", seed, count, shard_size, spec or {"n": 3}, {"rule": "all train"})


def _prepare(manifest, folder):
    return {"offset": 0.5}


def _make(manifest, shared, unit):
    rng = np.random.default_rng([manifest.seed, unit])
    return {"x": rng.normal(size=(3, 3)).astype(np.float32) + shared["offset"], "ok": np.asarray(unit % 5 != 3),
            "wall_s": np.asarray(0.01)}


def test_samples_stream_into_shards_and_a_stopped_run_resumes(tmp_path):
    out = tmp_path / "data"
    store = open_dataset(out, _manifest())
    first = run_generator(store, _prepare, _make, progress=False, limit=6)
    assert (first.made, first.skipped, first.failed) == (6, 0, 1)
    assert sorted(p.name for p in (out / "shards").iterdir()) == ["shard-00000.npz"]  # units 0-3 packed
    assert sorted(p.name for p in (out / "pending").iterdir()) == ["0000004.npz", "0000005.npz"]
    packed = (out / "shards" / "shard-00000.npz").stat().st_mtime_ns
    again = run_generator(open_dataset(out, _manifest()), _prepare, _make, progress=False)
    assert (again.made, again.skipped) == (4, 6)
    assert (out / "shards" / "shard-00000.npz").stat().st_mtime_ns == packed  # never rewritten
    assert sorted(p.name for p in (out / "shards").iterdir()) == [f"shard-0000{k}.npz" for k in range(3)]
    assert not any((out / "pending").iterdir())
    data = ShardStore(out, Manifest.read(out)).load()
    assert data["unit"].tolist() == list(range(10))
    whole = [_make(_manifest(), {"offset": 0.5}, u)["x"] for u in range(10)]
    assert np.array_equal(data["x"], np.stack(whole))  # the same samples as one uninterrupted run
    assert json.loads((out / "last_run.json").read_text())["made"] == 4
    nothing = run_generator(open_dataset(out, _manifest()), _prepare, _make, progress=False)
    assert nothing.made == 0


def test_a_sample_left_pending_beside_its_shard_loads_once(tmp_path):
    """A run stopped between writing a shard and removing its pending files leaves copies
    of units the shard holds: they load once (the shard's copy) and the generator removes
    them. A pending unit its shard's file lacks (a packed subset) is a sample of its own."""
    out = tmp_path / "data"
    run_generator(open_dataset(out, _manifest()), _prepare, _make, progress=False, limit=4)
    shard = ShardStore(out, Manifest.read(out))
    data = shard.load()
    row = {k: v[2] for k, v in data.items()}
    np.savez(shard.sample_path(2), **row)                                              # stranded copy of unit 2
    np.savez(shard.sample_path(3), **{**{k: v[3] for k, v in data.items()}, "x": data["x"][3] + 9})
    np.savez(shard.sample_path(9), **{**{k: v[0] for k, v in data.items()}, "unit": np.asarray(9)})
    again = shard.load()
    assert again["unit"].tolist() == [0, 1, 2, 3, 9]
    assert np.array_equal(again["x"][:4], data["x"])         # the shard's copy wins
    assert run_generator(open_dataset(out, _manifest()), _prepare, _make, progress=False, limit=0).made == 0
    assert sorted(p.name for p in (out / "pending").iterdir()) == ["0000009.npz"]   # the copies removed on opening
    # a shard file that holds units 0 and 2 of its range only (a pack of some splits)
    np.savez_compressed(shard.shard_path(0), **{k: v[[0, 2]] for k, v in data.items()})
    np.savez(shard.sample_path(1), **{k: v[1] for k, v in data.items()})
    np.savez(shard.sample_path(2), **row)
    assert [p.name for p in shard.stranded_samples()] == ["0000002.npz"]
    assert shard.load()["unit"].tolist() == [0, 1, 2, 9]


def test_a_dataset_grows_but_never_mixes_settings(tmp_path):
    out = tmp_path / "data"
    run_generator(open_dataset(out, _manifest(count=6)), _prepare, _make, progress=False)
    grown = run_generator(open_dataset(out, _manifest(count=9)), _prepare, _make, progress=False)
    assert grown.made == 3  # units 6-8; the short shard of units 4-5 is reopened, not made again
    assert ShardStore(out, Manifest.read(out)).load()["unit"].tolist() == list(range(9))
    with pytest.raises(DatasetError, match="seed"):
        open_dataset(out, _manifest(count=9, seed=2))
    with pytest.raises(DatasetError, match="spec"):
        open_dataset(out, _manifest(count=9, spec={"n": 4}))


def test_a_dataset_never_takes_over_a_users_folder(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    with pytest.raises(OutputFolderError, match="not written by tryon"):
        open_dataset(mine, _manifest())
    assert (mine / "notes.txt").read_text() == "keep me"
    with pytest.raises(DatasetError, match="no dataset"):
        Manifest.read(mine)


def test_bodies_are_drawn_per_index_and_uniform_in_bmi_and_height():
    ranges = BodyRanges()
    draws = [draw_measurements(3, i, ranges) for i in range(4000)]
    assert draws[17] == draw_measurements(3, 17, ranges) and draws[17] != draw_measurements(4, 17, ranges)
    bmi = np.array([d[3] for d in draws])
    assert bmi.min() >= 17 and bmi.max() <= 45
    counts, _ = np.histogram(bmi, bins=7, range=(17, 45))
    assert counts.min() > 0.8 * len(draws) / 7  # uniform within sampling noise
    for gender in ("female", "male"):
        h = np.array([d[2] for d in draws if d[0] == gender])
        lo, hi = ranges.height_cm[gender]
        assert lo <= h.min() and h.max() <= hi and abs(h.mean() - 0.5 * (lo + hi)) < 1.0
    assert 0.45 < np.mean([d[0] == "female" for d in draws]) < 0.55


def test_body_ranges_outside_the_supported_bodies_are_refused():
    with pytest.raises(TryonError, match="BMI range 12-45"):
        BodyRanges(bmi=(12, 45))
    with pytest.raises(TryonError, match="height range"):
        BodyRanges(height_cm={"female": (120, 180), "male": (160, 200)})
    with pytest.raises(TryonError, match="gender"):
        BodyRanges(genders=("robot",))
    assert BodyRanges.from_dict(BodyRanges().to_dict()) == BodyRanges()
