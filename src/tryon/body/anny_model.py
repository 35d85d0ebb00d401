"""The Anny body model (Brégier et al., "Human Mesh Modeling for Anny Body", ECCV 2026;
Apache-2.0 code, CC0 MakeHuman data), loaded once per process.

`BodyModel.rest_shape(params)` gives a `BodyShape`: Anny's rest mesh for a set of
phenotype and local-change parameters, translated so the soles touch z = 0 and the body
is centred on the z axis, with its skeleton (bone heads, parents) and skinning weights.
The pelvis (root bone) lies on the z axis. The rest pose is Anny's own (arms about 45 degrees down, elbows slightly bent); `pose`
turns it into the A-pose or T-pose.

The first use builds Anny's blend-shape cache (about 90 s, about 1.1 GB) in
``ANNY_CACHE_DIR`` (default ``~/.cache/anny``); later loads take under a second. Anny
writes its cache files in place, so processes that start together (test workers, service
workers) take a lock on the cache folder while one of them builds or loads it.
"""

from __future__ import annotations

import contextlib
import fcntl
import io
import logging
import os
import sys
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from tryon.errors import TryonError
from tryon.io.quiet import init_warp_quietly

DTYPE = torch.float64

# Local shape controls (MakeHuman targets) that the fit may use besides the phenotypes:
# the girths people are measured at, belly, buttocks and limb fat. Each runs from -1
# (the "decr" target) to +1 (the "incr" target).
LOCAL_CHANGES = (
    "measure-bust-circ-incr",
    "measure-underbust-circ-incr",
    "measure-waist-circ-incr",
    "measure-hips-circ-incr",
    "stomach-pregnant-incr",
    "buttocks-volume-incr",
    "torso-scale-depth-incr",
    "torso-scale-horiz-incr",
    "l-upperleg-fat-incr",
    "r-upperleg-fat-incr",
    "l-upperarm-fat-incr",
    "r-upperarm-fat-incr",
    "measure-neck-circ-incr",
    # appended (stored shape vectors list the earlier ones first and stay valid): the
    # lengths and girths the anthropometric fit reaches besides chest, waist and hip
    "measure-thigh-circ-incr",
    "measure-upperleg-height-incr",
    "measure-shoulder-dist-incr",
    "measure-upperarm-length-incr",
    "measure-lowerarm-length-incr",
    "torso-scale-vert-incr",
    "hip-scale-vert-incr",
    "neck-scale-depth-incr",
    "l-lowerarm-fat-incr",
    "r-lowerarm-fat-incr",
    "neck-scale-horiz-incr",
    "l-hand-scale-incr",
    "r-hand-scale-incr",
)
# how many of LOCAL_CHANGES the pinned fit (`fit_body(prior=False)`) and the datasets use
LEGACY_LOCAL_CHANGES = 13
PHENOTYPES = ("gender", "age", "muscle", "weight", "height", "proportions")
# Anny's "morphological age" calibration (data/shape_calibration in the anny package):
# Anny age parameter <-> years, piecewise linear.
ANNY_AGE_ANCHORS = (0.0, 0.05, 0.215, 0.415, 0.67, 0.77, 0.83, 1.0)
YEARS_ANCHORS = (0.0, 1.0, 4.0, 11.0, 16.0, 18.0, 64.0, 110.0)

log = logging.getLogger(__name__)


def years_to_anny_age(years: float) -> float:
    return float(np.interp(years, YEARS_ANCHORS, ANNY_AGE_ANCHORS))


def anny_age_to_years(age: float) -> float:
    return float(np.interp(age, ANNY_AGE_ANCHORS, YEARS_ANCHORS))


@dataclass
class ShapeParams:
    """Anny shape parameters. Phenotypes lie in [0, 1] (gender 0 = male, 1 = female; age
    in Anny units, see `years_to_anny_age`); local changes in [-1, 1], keyed by the names
    in `LOCAL_CHANGES`."""

    gender: float = 0.0
    age: float = 0.72
    muscle: float = 0.5
    weight: float = 0.5
    height: float = 0.5
    proportions: float = 0.5
    local: dict[str, float] = field(default_factory=dict)

    def phenotype_tensor(self) -> torch.Tensor:
        return torch.tensor([[getattr(self, k) for k in PHENOTYPES]], dtype=DTYPE)

    def local_tensor(self) -> torch.Tensor:
        unknown = sorted(set(self.local) - set(LOCAL_CHANGES))
        if unknown:
            raise TryonError(f"unknown local shape changes {unknown}; known: {list(LOCAL_CHANGES)}")
        return torch.tensor([[float(self.local.get(k, 0.0)) for k in LOCAL_CHANGES]], dtype=DTYPE)

    def to_dict(self) -> dict:
        d = {k: float(getattr(self, k)) for k in PHENOTYPES}
        d["local"] = {k: float(v) for k, v in self.local.items() if abs(v) > 1e-9}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ShapeParams":
        try:
            return cls(**{k: float(d[k]) for k in PHENOTYPES if k in d}, local=dict(d.get("local", {})))
        except (TypeError, ValueError) as exc:
            raise TryonError(f"body shape parameters are malformed ({exc}); expected numbers for {list(PHENOTYPES)}") from exc


@dataclass
class BodyShape:
    """A body in its rest pose: vertices [V,3] (m, Z up, soles at z = 0, facing -Y),
    faces [F,3], skeleton (bone heads [J,3], parents [J], labels) and skinning weights
    (`weight_index` [V,K], `weight` [V,K], rows summing to one)."""

    vertices: torch.Tensor
    faces: np.ndarray
    bone_heads: torch.Tensor
    bone_parents: list[int]
    bone_labels: list[str]
    weight_index: np.ndarray
    weight: np.ndarray
    params: ShapeParams

    def bone(self, label: str) -> int:
        try:
            return self.bone_labels.index(label)
        except ValueError:
            raise TryonError(f"the body has no bone {label!r}") from None

    def head(self, label: str) -> np.ndarray:
        return self.bone_heads[self.bone(label)].detach().numpy()

    def detached(self) -> "BodyShape":
        return BodyShape(self.vertices.detach(), self.faces, self.bone_heads.detach(), self.bone_parents,
                         self.bone_labels, self.weight_index, self.weight, self.params)


def anny_cache_dir() -> Path:
    return Path(os.environ.get("ANNY_CACHE_DIR", str(Path.home() / ".cache" / "anny")))


@contextlib.contextmanager
def cache_lock(cache: Path, wait_s: float = 900.0):
    """An exclusive lock on the Anny cache folder for the block: other processes wait for
    a build under way, at most `wait_s` seconds. A cache folder this process cannot write
    (a prebuilt, read-only one) is only read, so it needs no lock."""
    try:
        cache.mkdir(parents=True, exist_ok=True)
        fh = open(cache / ".tryon-build.lock", "a")
    except OSError:
        fh = None
    if fh is None:  # outside the except block: errors of the block are not chained to this one
        yield
        return
    with fh:
        deadline = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise TryonError(f"another process has held the Anny cache lock {cache / '.tryon-build.lock'} "
                                     f"for over {wait_s:.0f} s (building or loading the cache): stop it, or give "
                                     "this one its own ANNY_CACHE_DIR")
                time.sleep(0.2)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


@lru_cache(maxsize=1)
def body_model() -> "BodyModel":
    """The process-wide body model (built or loaded from the cache on first use)."""
    return BodyModel()


class BodyModel:
    """Anny with the phenotype set and the `LOCAL_CHANGES` controls, in float64."""

    def __init__(self) -> None:
        try:
            import anny
        except ImportError as exc:  # pragma: no cover - anny is a pinned dependency
            raise TryonError("the 'anny' package is missing; run `make demo` or pip install -e .") from exc
        cache = anny_cache_dir()
        fresh = not (cache / "v1").exists() and not any(cache.glob("v*/build_compact_model_data_*"))
        if fresh:
            print(f"building the Anny body model cache in {cache} (first use: about 90 s, 1.1 GB)...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        os.environ.setdefault("ANNY_CACHE_DIR", str(cache))
        anny.paths.set_anny_cache_path(cache)
        init_warp_quietly()  # anny skins with warp
        with cache_lock(cache), contextlib.redirect_stdout(io.StringIO()):
            self.anny = anny.Anny(local_changes=list(LOCAL_CHANGES)).to(DTYPE)
        self.anny.requires_grad_(False)
        log.info("Anny loaded in %.1f s", time.perf_counter() - t0)
        missing = [k for k in LOCAL_CHANGES if k not in self.anny.local_change_labels]
        if missing:  # pragma: no cover - depends on the anny version
            raise TryonError(f"this anny version lacks the local changes {missing}")
        self._lc_order = [self.anny.local_change_labels.index(k) for k in LOCAL_CHANGES]
        self._ph_order = [self.anny.phenotype_labels.index(k) for k in PHENOTYPES]
        self.faces = np.asarray(self.anny.faces, dtype=np.int64)
        self.bone_labels = list(self.anny.bone_labels)
        self.bone_parents = [int(p) for p in self.anny.bone_parents]
        self.weight_index = self.anny.vertex_bone_indices.numpy().astype(np.int64)
        w = self.anny.vertex_bone_weights.numpy().astype(np.float64)
        self.weight = w / w.sum(1, keepdims=True)

    def rest_vertices(self, phenotypes: torch.Tensor, local: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Differentiable rest vertices [V,3] and bone heads [J,3] (Anny's frame) for
        phenotypes [1,6] in `PHENOTYPES` order and local changes [1,L] in `LOCAL_CHANGES` order."""
        ph = torch.full((1, len(self.anny.phenotype_labels)), 0.5, dtype=DTYPE)
        ph = ph.index_copy(1, torch.tensor(self._ph_order), phenotypes.to(DTYPE))
        lc = torch.zeros((1, len(self.anny.local_change_labels)), dtype=DTYPE)
        lc = lc.index_copy(1, torch.tensor(self._lc_order), local.to(DTYPE))
        fa = torch.zeros((1, len(self.anny.facial_action_labels)), dtype=DTYPE)
        coeffs = self.anny._get_phenotype_blendshape_coefficients(ph, lc, fa)
        out = self.anny.get_rest_model(coeffs)
        return out["rest_vertices"][0], out["rest_bone_heads"][0]

    def rest_shape(self, params: ShapeParams, phenotypes: torch.Tensor | None = None, local: torch.Tensor | None = None) -> BodyShape:
        """The body of `params` standing on z = 0, centred on the z axis. Pass `phenotypes` /
        `local` tensors (e.g. requiring grad) to override the values in `params`."""
        ph = params.phenotype_tensor() if phenotypes is None else phenotypes
        lc = params.local_tensor() if local is None else local
        v, heads = self.rest_vertices(ph, lc)
        root = heads[0].detach()
        offset = torch.stack([root[0], root[1], v[:, 2].min()])
        return BodyShape(v - offset, self.faces, heads - offset, self.bone_parents, self.bone_labels,
                         self.weight_index, self.weight, params)
