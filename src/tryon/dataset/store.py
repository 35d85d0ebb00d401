"""A dataset folder: a manifest, finished shards that are never rewritten, and the
samples of unfinished shards, each in its own file until its shard is complete.

    DIR/manifest.json           what the data is and how to make it again (`Manifest`)
    DIR/shards/shard-00012.npz  samples [12 S, 13 S) of the unit list, stacked
    DIR/pending/000123.npz      one finished sample whose shard is not complete yet
    DIR/references/...          what every sample shares (e.g. the reference drapes)

A unit is one sample of the generator (one body in one size, one clip, one view...);
units are numbered, and shard k holds units k S ... (k + 1) S - 1 with S the manifest's
`shard_size`. A sample is a flat dict of numpy arrays; its shard stacks each key over
its units, so every sample of a kind must give the same keys and shapes (failed samples
give the same keys, with `ok` False). Every file is written under a temporary name and
renamed, so a stopped run leaves finished files only, and a resumed run skips them.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from tryon.errors import InputFileError, TryonError
from tryon.io.atomic import atomic_write
from tryon.io.json_safe import dumps_json
from tryon.io.npz import read_npz

MANIFEST = "manifest.json"


class DatasetError(TryonError):
    """A dataset folder is missing, damaged or made with other settings."""


def software_version() -> str:
    """tryon's version, with the commit when it runs from a git checkout (provenance)."""
    import subprocess

    from tryon import __version__

    try:
        commit = subprocess.run(["git", "-C", str(Path(__file__).parent), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return f"{__version__}+g{commit}" if commit else __version__


@dataclass
class Manifest:
    """Everything that determines a dataset's samples (so it can be made again), plus the
    split rule fixed before any training. `spec` holds the generator's own settings;
    `count` is the number of units and may grow (units are drawn per index)."""

    kind: str
    generator_version: int
    software_version: str
    seed: int
    count: int
    shard_size: int
    spec: dict
    split: dict
    created: str = ""
    notes: dict = field(default_factory=dict)

    def same_data(self, other: "Manifest") -> list[str]:
        """The settings in which `other` would make different samples (count excluded)."""
        diff = []
        for key in ("kind", "generator_version", "seed", "shard_size", "spec", "split"):
            if getattr(self, key) != getattr(other, key):
                diff.append(key)
        return diff

    def to_json(self) -> str:
        return dumps_json(asdict(self), indent=2)

    @classmethod
    def read(cls, folder: str | Path) -> "Manifest":
        path = Path(folder) / MANIFEST
        if not path.is_file():
            raise DatasetError(f"{folder} holds no dataset ({MANIFEST} missing); make one with `tryon dataset ...`")
        try:
            d = json.loads(path.read_text())
            return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})
        except (ValueError, TypeError, KeyError) as exc:
            raise DatasetError(f"{path} is not a dataset manifest ({exc})") from exc


def sample_rows(arrays: dict[str, np.ndarray], split: str | None = None, ok_only: bool = True) -> np.ndarray:
    """Indices of a loaded dataset's samples in `split` (all splits: None), the failed ones
    left out unless `ok_only` is false."""
    keep = np.ones(len(arrays["unit"]), bool)
    if split is not None:
        keep &= arrays["split"] == split
    if ok_only:
        keep &= arrays["ok"].astype(bool)
    return np.nonzero(keep)[0]


class ShardStore:
    """Reads and writes the samples of one dataset folder."""

    def __init__(self, folder: str | Path, manifest: Manifest):
        self.folder = Path(folder)
        self.manifest = manifest
        self.shards = self.folder / "shards"
        self.pending = self.folder / "pending"

    # -- writing
    def write_manifest(self) -> None:
        with atomic_write(self.folder / MANIFEST, "w") as fh:
            fh.write(self.manifest.to_json())

    def shard_path(self, k: int) -> Path:
        return self.shards / f"shard-{k:05d}.npz"

    def sample_path(self, unit: int) -> Path:
        return self.pending / f"{unit:07d}.npz"

    def shard_units(self, k: int) -> range:
        s = self.manifest.shard_size
        return range(k * s, min((k + 1) * s, self.manifest.count))

    def num_shards(self) -> int:
        return -(-self.manifest.count // self.manifest.shard_size)

    def done_units(self) -> set[int]:
        done = set()
        for k in range(self.num_shards()):
            if self.shard_path(k).exists() and self._shard_complete(k):
                done.update(self.shard_units(k))
        if self.pending.is_dir():
            for p in self.pending.glob("*.npz"):
                if p.stem.isdigit() and int(p.stem) < self.manifest.count:
                    done.add(int(p.stem))
        return done

    def _shard_complete(self, k: int) -> bool:
        """A shard written while the count was smaller can miss units the count now has."""
        try:
            units = read_npz(self.shard_path(k), "dataset shard", allow_large=True, keys=("unit",))["unit"]
            return len(units) == len(self.shard_units(k))
        except InputFileError:
            return False

    def stranded_samples(self) -> list[Path]:
        """Pending files of units their shard's file already holds: copies a run stopped
        between writing a shard and removing its pending files left behind."""
        out: list[Path] = []
        if not self.pending.is_dir():
            return out
        for k in range(self.num_shards()):
            pending = [self.sample_path(u) for u in self.shard_units(k) if self.sample_path(u).exists()]
            if pending and self.shard_path(k).exists():
                try:
                    held = set(read_npz(self.shard_path(k), "dataset shard", allow_large=True, keys=("unit",))["unit"].tolist())
                except InputFileError:
                    continue
                out += [p for p in pending if int(p.stem) in held]
        return out

    def remove_stranded_samples(self) -> int:
        """Removes `stranded_samples`; how many there were."""
        stranded = self.stranded_samples()
        for p in stranded:
            p.unlink()
        return len(stranded)

    def reopen_short_shards(self) -> None:
        """After the count grew, the last shard of the old count may be short: its samples
        go back to pending (nothing is made again) so that it packs with the new units."""
        for k in range(self.num_shards()):
            path = self.shard_path(k)
            if path.exists() and not self._shard_complete(k):
                shard = read_npz(path, "dataset shard")
                self.pending.mkdir(parents=True, exist_ok=True)
                for row, unit in enumerate(shard["unit"].tolist()):
                    with atomic_write(self.sample_path(unit), "wb") as fh:
                        np.savez(fh, **{key: value[row] for key, value in shard.items()})
                path.unlink()

    def put(self, unit: int, sample: dict[str, np.ndarray]) -> None:
        """Store one finished sample; pack its shard once all of the shard's units are in."""
        self.pending.mkdir(parents=True, exist_ok=True)
        with atomic_write(self.sample_path(unit), "wb") as fh:
            np.savez(fh, **{**sample, "unit": np.asarray(unit)})
        self.pack(unit // self.manifest.shard_size)

    def pack(self, k: int) -> bool:
        """Stack the pending samples of shard k into its file (once all are there)."""
        units = self.shard_units(k)
        paths = [self.sample_path(u) for u in units]
        if not all(p.exists() for p in paths):
            return False
        samples = [read_npz(p, "dataset sample") for p in paths]
        keys = sorted(samples[0])
        for u, s in zip(units, samples):
            if sorted(s) != keys:
                raise DatasetError(f"sample {u} in {self.pending} has keys {sorted(s)}, its shard's first has {keys}")
        self.shards.mkdir(parents=True, exist_ok=True)
        with atomic_write(self.shard_path(k), "wb") as fh:
            np.savez_compressed(fh, **{key: np.stack([s[key] for s in samples]) for key in keys})
        for p in paths:
            p.unlink()
        return True

    # -- reading
    def load(self, keys: list[str] | None = None) -> dict[str, np.ndarray]:
        """Every finished sample (shards and pending ones), stacked and ordered by unit."""
        parts: list[dict[str, np.ndarray]] = []
        for k in range(self.num_shards()):
            if self.shard_path(k).exists():
                parts.append(read_npz(self.shard_path(k), "dataset shard"))
        if self.pending.is_dir():
            for p in sorted(self.pending.glob("*.npz")):
                s = read_npz(p, "dataset sample")
                parts.append({key: value[None] for key, value in s.items()})
        if not parts:
            raise DatasetError(f"{self.folder} holds no samples yet; run the generator (it resumes)")
        keys = keys or sorted(set.intersection(*(set(p) for p in parts)))  # samples of older versions may lack new keys
        out = {key: np.concatenate([p[key] for p in parts]) for key in set(keys) | {"unit"}}
        order = np.argsort(out["unit"], kind="stable")   # shards first: a unit in both keeps its shard's copy
        units = out["unit"][order]
        first = np.ones(len(units), bool)
        first[1:] = units[1:] != units[:-1]    # a pending copy left beside the shard written from it
        order = order[first]
        return {key: value[order] for key, value in out.items()}
