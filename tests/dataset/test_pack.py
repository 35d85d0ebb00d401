"""Compact copies of datasets (`tryon dataset pack`) on small synthetic pose datasets: half
precision, updates that keep unchanged files, no sample twice, and no folder lost."""

import shutil
import subprocess
import sys

import numpy as np
import pytest

import tryon.dataset.pack as pack_module
from tryon.dataset import DatasetError, Manifest, ShardStore
from tryon.dataset.pack import pack_dataset
from tryon.errors import TryonError


def _dataset(folder, units, count=5, shard_size=2, created="2026-11-26T10:00:00+0000", seed=0):
    """A pose dataset of `count` units with the samples `units` made (shards pack as they fill)."""
    manifest = Manifest("poses", 1, "test", seed, count, shard_size, {"frames": 2}, {"rule": "odd units test"},
                        created=created)
    folder.mkdir(parents=True, exist_ok=True)
    store = ShardStore(folder, manifest)
    store.write_manifest()
    (folder / "rest.npz").write_bytes(b"the rest drape")
    (folder / "rest.json").write_text("{}")
    (folder / "last_run.json").write_text("{}")   # the generator's bookkeeping: not copied
    for u in units:
        store.put(u, _sample(u))
    return store


def _sample(u, shift=0.0):
    x = np.random.default_rng(u).normal(size=(2, 4, 3)).astype(np.float32) + shift
    return {"split": np.asarray("test" if u % 2 else "train"), "ok": np.asarray(True), "x": x}


def _load(folder):
    return ShardStore(folder, Manifest.read(folder)).load()


def test_a_pack_is_half_precision_and_grows_by_its_new_files_only(tmp_path):
    src, dst = tmp_path / "poses", tmp_path / "packed"
    store = _dataset(src, [0, 1, 2])
    pack_dataset(src, dst)
    a = _load(dst)
    assert a["unit"].tolist() == [0, 1, 2] and a["x"].dtype == np.float16
    assert np.abs(a["x"].astype(np.float32) - store.load()["x"]).max() < 0.01
    assert (dst / "rest.npz").read_bytes() == b"the rest drape" and not (dst / "last_run.json").exists()
    assert Manifest.read(dst).notes["packed"] == {"splits": None}
    first = dst / "shards" / "shard-00000.npz"
    before = (first.read_bytes(), first.stat().st_ino)
    assert (dst / "pending" / "0000002.npz").exists()
    for u in (3, 4):   # unit 2 joins shard 1, unit 4 fills the short shard 2
        store.put(u, _sample(u))
    pack_dataset(src, dst)
    assert (first.read_bytes(), first.stat().st_ino) == before    # kept, not written again
    assert not (dst / "pending" / "0000002.npz").exists()
    assert _load(dst)["unit"].tolist() == [0, 1, 2, 3, 4]


def test_a_pending_copy_of_a_unit_its_shard_holds_is_not_packed(tmp_path):
    src, dst = tmp_path / "poses", tmp_path / "packed"
    store = _dataset(src, [0, 1, 2])
    np.savez(store.sample_path(1), **{**_sample(1), "unit": np.asarray(1)})    # left by a run stopped mid-write
    pack_dataset(src, dst)
    assert sorted(p.name for p in (dst / "pending").iterdir()) == ["0000002.npz"]
    assert _load(dst)["unit"].tolist() == [0, 1, 2]


def test_packing_some_splits_and_then_others_makes_the_copy_again(tmp_path):
    src, dst = tmp_path / "poses", tmp_path / "packed"
    _dataset(src, range(5))
    assert _load(pack_dataset(src, dst, splits=["test"]))["unit"].tolist() == [1, 3]
    assert _load(pack_dataset(src, dst, splits=["train"]))["unit"].tolist() == [0, 2, 4]
    with pytest.raises(DatasetError, match="nowhere"):
        pack_dataset(src, tmp_path / "none", splits=["nowhere"])
    assert not (tmp_path / "none").exists()


def test_a_pack_that_fails_leaves_the_earlier_copy_as_it_was(tmp_path, monkeypatch):
    src, dst = tmp_path / "poses", tmp_path / "packed"
    store = _dataset(src, [0, 1, 2])
    pack_dataset(src, dst)
    store.put(3, _sample(3))

    def broken(arrays, splits):
        raise RuntimeError("disk full")

    monkeypatch.setattr(pack_module, "_packed", broken)
    with pytest.raises(RuntimeError):
        pack_dataset(src, dst)
    assert _load(dst)["unit"].tolist() == [0, 1, 2]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["packed", "poses"]   # no half-built copy left


def test_pack_refuses_folders_it_could_destroy(tmp_path):
    src = tmp_path / "poses"
    _dataset(src, [0, 1])
    for dst in (src, src / "packed", tmp_path):
        with pytest.raises(DatasetError, match="outside it"):
            pack_dataset(src, dst)
    other = tmp_path / "other"
    _dataset(other, [0])
    with pytest.raises(DatasetError, match="not a pack"):
        pack_dataset(src, other)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(TryonError, match="not written by tryon"):
        pack_dataset(src, mine)
    assert _load(other)["unit"].tolist() == [0] and (mine / "notes.txt").read_text() == "keep"
    assert _load(src)["unit"].tolist() == [0, 1]


def test_pack_refuses_a_dataset_a_generator_is_writing(tmp_path):
    src = tmp_path / "poses"
    _dataset(src, [0, 1])
    holder = subprocess.Popen([sys.executable, "-c", (
        "import fcntl, os, sys, time\n"
        f"fd = os.open({str(src / '.lock')!r}, os.O_RDWR | os.O_CREAT)\n"
        "fcntl.flock(fd, fcntl.LOCK_EX)\nprint('locked', flush=True)\ntime.sleep(60)\n")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(DatasetError, match="generator is writing"):
            pack_dataset(src, tmp_path / "packed")
    finally:
        holder.kill()
        holder.wait()
    assert _load(pack_dataset(src, tmp_path / "packed"))["unit"].tolist() == [0, 1]


def test_pack_replaces_only_an_earlier_pack_of_the_same_dataset_holding_nothing_else(tmp_path):
    src, dst = tmp_path / "poses", tmp_path / "packed"
    _dataset(src, [0, 1])
    pack_dataset(src, dst)
    (dst / "README.md").write_text("what this data is")
    with pytest.raises(DatasetError, match="README.md besides the pack"):
        pack_dataset(src, dst)
    (dst / "README.md").unlink()
    other = tmp_path / "other"
    _dataset(other, [0, 1], seed=7)
    with pytest.raises(DatasetError, match="other data .*seed"):
        pack_dataset(other, dst)
    # made again from scratch (same settings, new samples): its earlier pack is not reused
    shutil.rmtree(src)
    store = _dataset(src, [], created="2026-11-27T10:00:00+0000")
    for u in (0, 1):
        store.put(u, _sample(u, shift=1.0))
    with pytest.raises(DatasetError, match="created"):
        pack_dataset(src, dst)
    pack_dataset(src, dst, force=True)
    assert np.abs(_load(dst)["x"].astype(np.float32) - store.load()["x"]).max() < 0.01
