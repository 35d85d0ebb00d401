"""`BodyMotion`, the motion data itself (see `tryon.body.motion` for files and skinning);
its own module so that the BVH reader can build one without importing the motion loader
that dispatches to it."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tryon.body.anny_model import BodyShape
from tryon.body.pose import axis_angle, identity_pose
from tryon.errors import TryonError
from tryon.io.atomic import atomic_write
from tryon.limits import LIMITS, check_limit

MIN_FPS, MAX_FPS = 1.0, 1000.0


@dataclass
class BodyMotion:
    """Per-frame bone rotations [T,J,3] (axis-angle) for `bone_labels`, at `fps`."""

    rotations: np.ndarray
    bone_labels: list[str]
    fps: float
    root_translation: np.ndarray | None = None
    name: str = "motion"

    def __post_init__(self) -> None:
        r = np.asarray(self.rotations, dtype=np.float64)
        if r.ndim != 3 or r.shape[2] != 3 or r.shape[0] < 1 or r.shape[1] != len(self.bone_labels):
            raise TryonError(f"motion {self.name}: rotations must be [T, J, 3] with J = {len(self.bone_labels)} bone labels, got {r.shape}")
        if not np.isfinite(r).all():
            raise TryonError(f"motion {self.name}: rotations contain NaN or inf")
        plain = isinstance(self.fps, (int, float, np.number)) and not isinstance(self.fps, bool)
        if not plain or not MIN_FPS <= self.fps <= MAX_FPS:
            raise TryonError(f"motion {self.name}: fps must lie in [{MIN_FPS:g}, {MAX_FPS:g}] frames per second, got {self.fps!r}")
        self.fps = float(self.fps)
        check_limit(f"motion {self.name}: frames", len(r), LIMITS.max_frames, "max_frames")
        self.rotations = r
        if self.root_translation is None:
            self.root_translation = np.zeros((len(r), 3))
        t = np.asarray(self.root_translation, dtype=np.float64)
        if t.shape != (len(r), 3) or not np.isfinite(t).all():
            raise TryonError(f"motion {self.name}: root_translation must be finite [T, 3] = [{len(r)}, 3], got {t.shape}")
        self.root_translation = t

    @property
    def num_frames(self) -> int:
        return len(self.rotations)

    @property
    def duration(self) -> float:
        return (self.num_frames - 1) / self.fps

    def repeated(self, cycles: int, tolerance: float = 1e-3) -> "BodyMotion":
        """The motion played `cycles` times in a row. Only a cyclic motion (its last frame
        the first one again, within `tolerance` rad and m) repeats: its last frame is the
        next cycle's first, and a root that travels carries on from where the cycle ends."""
        if int(cycles) != cycles or cycles < 1:
            raise TryonError(f"motion {self.name}: the number of repetitions must be a whole number >= 1, got {cycles}")
        cycles = int(cycles)
        if cycles == 1:
            return self
        if self.num_frames < 2:
            raise TryonError(f"motion {self.name}: a single frame cannot repeat")
        turn = float(np.abs(self.rotations[-1] - self.rotations[0]).max())
        if turn > tolerance:
            raise TryonError(f"motion {self.name} is not a cycle (its last frame differs from its first by up to "
                             f"{turn:.3f} rad), so it cannot repeat")
        step = self.root_translation[-1] - self.root_translation[0]
        rotations = [self.rotations] + [self.rotations[1:]] * (cycles - 1)
        translation = [self.root_translation] + [self.root_translation[1:] + k * step for k in range(1, cycles)]
        return BodyMotion(np.concatenate(rotations), list(self.bone_labels), self.fps, np.concatenate(translation),
                          self.name)

    def pose_matrices(self, shape: BodyShape) -> np.ndarray:
        """Rotations [T,J_body,3,3] for the bones of `shape` (unnamed bones: identity)."""
        R = np.tile(identity_pose(shape)[None], (self.num_frames, 1, 1, 1))
        index = {lab: i for i, lab in enumerate(shape.bone_labels)}
        unknown = [lab for lab in self.bone_labels if lab not in index]
        if len(unknown) == len(self.bone_labels):
            raise TryonError(f"motion {self.name}: none of its bones exist in the body (e.g. {unknown[:3]})")
        cols = [j for j, lab in enumerate(self.bone_labels) if lab in index]
        R[:, [index[self.bone_labels[j]] for j in cols]] = axis_angle(self.rotations[:, cols])
        return R

    def save(self, path: str | Path) -> Path:
        with atomic_write(path, "wb") as fh:
            np.savez_compressed(fh, rotations=self.rotations, bone_labels=np.array(self.bone_labels), fps=self.fps,
                                root_translation=self.root_translation, name=self.name)
        return Path(path)
