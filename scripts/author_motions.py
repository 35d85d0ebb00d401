"""Author the built-in body motions shipped in src/tryon/body/data/motions (walk,
arm-raise, turn) as per-frame joint rotations on Anny's average adult body.

Run from the repository root:  .venv/bin/python scripts/author_motions.py
The motions are keyed by bone label, so they play on any Anny body; joint angles are
the usual textbook ranges of a relaxed walk (hip flexion about +-25 degrees, knee up to
55 degrees in swing, counter-swinging arms, a little pelvis rotation and vertical bob).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tryon.body.anny_model import ShapeParams, body_model
from tryon.body.motion import BodyMotion, smoothstep
from tryon.body.pose import arm_pose, axis_angle, matrix_to_axis_angle

FPS = 30.0
OUT = Path(__file__).resolve().parents[1] / "src" / "tryon" / "body" / "data" / "motions"


def rot(axis, deg: float) -> np.ndarray:
    a = np.asarray(axis, dtype=float)
    return axis_angle(a / np.linalg.norm(a) * np.radians(deg))


def elbow_flexion(shape, side: str, deg: float) -> np.ndarray:
    """Rotation bending the (straightened) forearm towards the front by `deg`."""
    upper = shape.head(f"lowerarm01.{side}") - shape.head(f"upperarm01.{side}")
    return rot(np.cross(upper, [0.0, -1.0, 0.0]), deg)


def walk(shape, cycle: float = 1.1, cycles: int = 2) -> BodyMotion:
    base = arm_pose(shape, 45.0)
    b = shape.bone
    t = np.arange(0.0, cycle * cycles + 1e-9, 1.0 / FPS)
    frames, trans = [], []
    for tk in t:
        phi = 2 * np.pi * tk / cycle
        R = base.copy()
        for side, phase in (("L", 0.0), ("R", np.pi)):
            p = phi + phase
            R[b(f"upperleg01.{side}")] = rot([1, 0, 0], -25.0 * np.sin(p))  # + = forwards
            R[b(f"lowerleg01.{side}")] = rot([1, 0, 0], 5.0 + 50.0 * max(0.0, np.cos(p)) ** 2)
            R[b(f"foot.{side}")] = rot([1, 0, 0], -8.0 * np.sin(p))
            R[b(f"upperarm01.{side}")] = rot([1, 0, 0], 15.0 * np.sin(p)) @ base[b(f"upperarm01.{side}")]  # opposite leg
            R[b(f"lowerarm01.{side}")] = elbow_flexion(shape, side, 15.0 + 10.0 * max(0.0, -np.sin(p))) @ base[b(f"lowerarm01.{side}")]
        R[b("root")] = rot([0, 0, 1], 4.0 * np.sin(phi))
        R[b("spine03")] = rot([0, 0, 1], -6.0 * np.sin(phi))
        frames.append(R)
        trans.append([0.0, 0.0, -0.012 * 0.5 * (1 - np.cos(2 * phi))])
    return _pack("walk", shape, frames, np.asarray(trans))


def arm_raise(shape, up: float = 1.2, hold: float = 0.4, top_deg: float = 110.0) -> BodyMotion:
    b = shape.bone
    t = np.arange(0.0, 2 * up + hold + 1e-9, 1.0 / FPS)
    frames = []
    for tk in t:
        s = smoothstep(tk / up) if tk < up + hold else smoothstep((2 * up + hold - tk) / up)
        angle = 45.0 + (top_deg - 45.0) * float(s)
        R = arm_pose(shape, angle)
        lift = max(0.0, angle - 80.0) * 0.35  # the shoulder girdle rises with the arm
        R[b("clavicle.L")] = rot([0, 1, 0], -lift)
        R[b("clavicle.R")] = rot([0, 1, 0], lift)
        frames.append(R)
    return _pack("arm-raise", shape, frames, np.zeros((len(t), 3)))


def turn(shape, half: float = 1.5, deg: float = 90.0) -> BodyMotion:
    base = arm_pose(shape, 45.0)
    b = shape.bone
    t = np.arange(0.0, 2 * half + 1e-9, 1.0 / FPS)
    frames = []
    for tk in t:
        s = smoothstep(tk / half) if tk < half else smoothstep((2 * half - tk) / half)
        R = base.copy()
        R[b("root")] = rot([0, 0, 1], deg * float(s))
        frames.append(R)
    return _pack("turn", shape, frames, np.zeros((len(t), 3)))


def _pack(name: str, shape, frames: list[np.ndarray], trans: np.ndarray) -> BodyMotion:
    R = np.stack(frames)
    moved = np.abs(R - np.eye(3)).max(axis=(0, 2, 3)) > 1e-12
    labels = [lab for lab, m in zip(shape.bone_labels, moved) if m]
    return BodyMotion(matrix_to_axis_angle(R[:, moved]), labels, FPS, trans, name)


def main() -> None:
    shape = body_model().rest_shape(ShapeParams())
    OUT.mkdir(parents=True, exist_ok=True)
    for motion in (walk(shape), arm_raise(shape), turn(shape)):
        path = motion.save(OUT / f"{motion.name}.npz")
        print(f"{path}: {motion.num_frames} frames, {motion.duration:.2f} s, {len(motion.bone_labels)} bones")


if __name__ == "__main__":
    main()
