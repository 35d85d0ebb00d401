"""The simulator refines a fabric class into a fabric (fabric from video, item 4): the
stretching and bending scales that make the simulated garment follow the observed one.

A class says where a fabric lies on the two axes of `fabric_classes` (log10 stretching and
bending stiffness) to within a bin. The refinement starts at the class's centre and moves
the two log10 scales of a base fabric (the mean measured fabric unless told) by
Levenberg-Marquardt: the residual is the simulated minus the observed garment over the
clip's frames (per vertex, over the garment's size), its Jacobian taken by forward
differences (two simulations; the scales are two numbers, so differences cost what
adjoints would and need no taped contact-rich steps). Each trial is a simulation of the
clip from its first observed frame with the body moving as observed.

`refine_scales` is the search over any `simulate(stretch_log10, bend_log10) -> frames`
(`tryon.fabric.blend.scaled_stiffness` scales a fabric by 10 to those powers);
`ClipToRefine` and `refine_clip_fabric` give it a garment on a moving body.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from tryon.errors import SimulationError, TryonError
from tryon.fabric.blend import scaled_stiffness
from tryon.fabric.wang2011 import WangFabric

FD_STEP = 0.02       # log10 units: a 4.7 % change of a stiffness
DAMPING = 1e-2       # Levenberg-Marquardt damping at the start, relative to diag(J^T J)
TRIALS = 3           # trial steps per iteration, the damping raised 8x after each that fails


@dataclass
class Refinement:
    """The refined log10 scales (relative to the base fabric), the fabric, and how it went."""

    stretch_log10: float
    bend_log10: float
    fabric: WangFabric
    error_start: float          # mean vertex distance / garment size at the start
    error: float                # ... at the refined scales
    simulations: int
    seconds: float
    history: list[dict] = field(default_factory=list)


def refine_scales(simulate: Callable[[float, float], np.ndarray], observed: np.ndarray, start: tuple[float, float],
                  bounds: tuple[tuple[float, float], tuple[float, float]], iterations: int = 3,
                  size: float | None = None, progress: Callable[[str], None] | None = None
                  ) -> tuple[np.ndarray, float, list[dict]]:
    """Levenberg-Marquardt on theta = (stretch_log10, bend_log10) inside `bounds`, the
    residual (simulate(theta) - observed)[1:] / size. Returns theta, its error (mean
    vertex distance / size) and the history (one row per simulation: theta, error). A
    simulation that fails counts as no better; a difference probe that beats the current
    scales is taken."""
    observed = np.asarray(observed, dtype=np.float64)
    if observed.ndim != 3 or len(observed) < 2:
        raise TryonError(f"the observed garment needs at least 2 frames of [N, 3] points, got {observed.shape}")
    size = size or float(np.linalg.norm(observed[0].max(0) - observed[0].min(0)))
    if not size > 0:
        raise TryonError("the observed garment has no extent (its first frame is a single point)")
    lo, hi = np.array([b[0] for b in bounds]), np.array([b[1] for b in bounds])
    history: list[dict] = []

    def residual(theta: np.ndarray) -> np.ndarray | None:
        try:
            x = np.asarray(simulate(float(theta[0]), float(theta[1])), dtype=np.float64)
        except SimulationError:
            x = None
        if x is None or x.shape != observed.shape or not np.isfinite(x).all():
            history.append({"theta": theta.tolist(), "error": None})
            return None
        r = (x[1:] - observed[1:]) / size
        history.append({"theta": theta.tolist(), "error": float(np.linalg.norm(r, axis=-1).mean())})
        if progress:
            progress(f"simulation {len(history)}: scales {theta[0]:+.3f} {theta[1]:+.3f} -> error {history[-1]['error']:.4f}")
        return r.ravel()

    theta = np.clip(np.asarray(start, dtype=np.float64), lo, hi)
    r = residual(theta)
    if r is None:
        raise TryonError(f"the simulation fails at the start scales {theta.tolist()}; nothing to refine from")
    loss = float(r @ r)
    damping = DAMPING
    for _ in range(iterations):
        J = np.zeros((len(r), 2))
        probes = []
        for k in range(2):
            step = FD_STEP if theta[k] + FD_STEP <= hi[k] else -FD_STEP
            t = theta.copy()
            t[k] += step
            rk = residual(t)
            if rk is None:
                continue
            J[:, k] = (rk - r) / step
            probes.append((float(rk @ rk), t, rk))
        A, g = J.T @ J, J.T @ r
        if not np.any(np.diag(A) > 0):
            break
        improved = False
        for _ in range(TRIALS):
            delta = np.linalg.solve(A + damping * np.diag(np.maximum(np.diag(A), 1e-12)), -g)
            trial = np.clip(theta + delta, lo, hi)
            if np.allclose(trial, theta, atol=1e-4):
                break
            rt = residual(trial)
            if rt is not None and float(rt @ rt) < loss:
                theta, r, loss = trial, rt, float(rt @ rt)
                damping = max(damping / 4, 1e-4)
                improved = True
                break
            damping *= 8
        best_probe = min(probes, key=lambda p: p[0], default=None)
        if best_probe is not None and best_probe[0] < loss:
            loss, theta, r = best_probe
            improved = True
        if not improved:
            break
    return theta, float(np.linalg.norm(r.reshape(-1, 3), axis=-1).mean()), history


@dataclass
class ClipToRefine:
    """A garment on a moving body, as observed: the garment's vertices per frame
    (`observed` [F,N,3], `frame_time` apart; frame 0 is where the simulation starts), its
    rest shape (`uv`, `faces`, `corner_uv`), the body (`shape`, its pose at frame 0
    `start_pose` [J,3,3], and `motion`, which starts one motion frame after frame 0:
    `motion_after`), and the contact settings the garment was draped with."""

    shape: object
    start_pose: np.ndarray
    motion: object
    observed: np.ndarray
    frame_time: float
    uv: np.ndarray
    faces: np.ndarray
    corner_uv: np.ndarray
    garment: str
    thickness: float
    friction: float
    dt: float = 0.01

    def simulate(self, fabric: WangFabric) -> np.ndarray:
        """The garment simulated from frame 0 at rest in `fabric`: [F,N,3] at the frame times."""
        from tryon.drape.animate import GarmentAtRest, garment_motion_scene
        from tryon.sim.runner import simulate

        frames = len(self.observed)
        duration = (frames - 1) * self.frame_time
        at = GarmentAtRest(self.observed[0], self.uv, self.faces, self.corner_uv, self.garment)
        scene = garment_motion_scene(self.shape, self.start_pose, at, fabric, self.motion, self.thickness,
                                     self.friction, self.dt, duration, blend_time=1.0 / self.motion.fps)
        scene.frame_time = self.frame_time
        result = simulate(scene, progress=False)
        times = np.asarray(result.times)
        want = np.arange(frames) * self.frame_time
        idx = np.abs(times[None, :] - want[:, None]).argmin(axis=1)
        if np.abs(times[idx] - want).max() > 0.25 * self.frame_time:
            raise TryonError("the refinement's simulation recorded no frame near an observed one")
        return np.asarray(result.positions)[idx]


def motion_after(motion, shape, t0: float, duration: float, fps: float = 30.0):
    """`motion` resampled at `fps` from time t0 + 1/fps on, the pose [J,3,3] at t0, and the
    root translation at t0: a scene blending from that pose over 1/fps into the resampled
    motion has the body at motion time t0 + t at every time t, moved by minus that
    translation (subtract it from the observed garment too)."""
    from tryon.body.motion import pose_at
    from tryon.body.motion_data import BodyMotion
    from tryon.body.pose import matrix_to_axis_angle

    poses = motion.pose_matrices(shape)
    times = t0 + (1 + np.arange(int(np.ceil(duration * fps)) + 1)) / fps
    rots, trans = zip(*(pose_at(motion, poses, float(t)) for t in times))
    start, start_trans = pose_at(motion, poses, t0)
    offset = np.asarray(start_trans, dtype=np.float64)
    moved = BodyMotion(matrix_to_axis_angle(np.stack(rots)), list(shape.bone_labels), fps, np.stack(trans) - offset,
                       f"{motion.name}@{t0:.2f}s")
    return moved, start, offset


def refine_clip_fabric(clip: ClipToRefine, start: tuple[float, float], bounds, base: WangFabric | None = None,
                       iterations: int = 3, progress: Callable[[str], None] | None = None) -> Refinement:
    """The fabric whose simulation follows `clip` best, from `start` (log10 scales of
    `base`, the mean measured fabric by default) within `bounds`."""
    from tryon.fabric.presets import mean_preset_fabric

    base = base or mean_preset_fabric()
    t0 = time.perf_counter()

    def fabric(s: float, b: float) -> WangFabric:
        return scaled_stiffness(base, 10.0 ** s, 10.0 ** b, name="refined")

    with torch.no_grad():
        theta, error, history = refine_scales(lambda s, b: clip.simulate(fabric(s, b)), clip.observed, start, bounds,
                                              iterations, progress=progress)
    return Refinement(float(theta[0]), float(theta[1]), fabric(*theta), float(history[0]["error"]), error,
                      len(history), time.perf_counter() - t0, history)
