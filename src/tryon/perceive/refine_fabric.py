"""The simulator refines a fabric class into a fabric (fabric from video, item 4): the
stretching stiffness that makes the simulated garment follow the observed one.

A class says where a fabric lies on the two axes of `fabric_classes` (log10 stretching and
bending stiffness) to within a bin. How well a simulated clip follows the observed garment
(the misfit: mean vertex distance over the garment's size, over the clip's frames) is a
sharp V in the stretching stiffness, with its minimum at the truth, and nearly flat in
bending (docs/FABRIC_FROM_VIDEO.md has the grid). So the refinement searches stretching
alone, by bracketing: a grid across the class's stretching range, then golden section
inside the best grid point's neighbours, keeping the best simulation seen (contact makes
the misfit rough at small steps, which is why local quadratic models stop early on it).
Bending stays at the class's centre, reported as unobserved. Before that the base fabric
(density, anisotropy and non-linearity, which the class does not fix) is chosen: each
measured fabric scaled to the class's centre is simulated, and the one that follows best
is kept.

`search_scale` is the search over any misfit of one number; `ClipToRefine` and
`refine_clip_fabric` give it a garment on a moving body.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from tryon.errors import SimulationError, TryonError
from tryon.fabric.blend import scaled_stiffness
from tryon.fabric.wang2011 import MEASURED_FABRICS, WangFabric
from tryon.perceive.fabric_classes import FabricClasses

GRID_POINTS = 5      # simulations spread over the stretching range, its ends included
GOLDEN_STEPS = 4     # the fewest simulations of the golden-section search inside the best grid point's neighbours
RESOLUTION_LOG10 = 0.025  # the golden section goes on until its bracket is this narrow (about 6 % in stiffness)
INVERSE_PHI = (math.sqrt(5.0) - 1.0) / 2.0
EDGE_MARGIN = 1e-3   # of the class's width: the searched range stays this far inside the class


@dataclass
class Refinement:
    """The refined fabric: where it lies on the class axes (log10 stiffness, absolute, as
    `FabricClasses.position` gives it), the measured fabric it was made from, and how the
    search went (one row per simulation)."""

    stretch_log10: float        # log10 N/m at 16 % strain (the class axis)
    bend_log10: float           # log10 N m, the class's centre: a clip does not show it
    fabric: WangFabric
    base: str                   # the measured fabric that followed best at the class's centre
    base_errors: dict[str, float]  # each base's misfit at the class's centre
    error_centre: float         # the chosen base's misfit at the class's centre
    error: float                # misfit at the refined stretching
    simulations: int
    seconds: float
    history: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def search_scale(misfit: Callable[[float], float], bounds: tuple[float, float], grid: int = GRID_POINTS,
                 golden: int = GOLDEN_STEPS) -> tuple[float, float, list[tuple[float, float]]]:
    """The x in `bounds` with the smallest misfit(x): `grid` points across the range, then
    `golden` golden-section points inside the best one's neighbours (one point looks
    between the best and its left neighbour only; two or more narrow the bracket). Returns
    the best x seen, its misfit, and every (x, misfit) in the order tried. A misfit of inf
    (a failed simulation) or NaN is never best; all failing is an error."""
    lo, hi = float(bounds[0]), float(bounds[1])
    if not hi > lo or grid < 2:
        raise TryonError(f"the search needs a range that rises and at least 2 grid points, got {bounds}, {grid}")
    seen: list[tuple[float, float]] = []

    def at(x: float) -> float:
        error = float(misfit(x))
        seen.append((x, error if error == error else math.inf))  # NaN counts as failed
        return seen[-1][1]

    xs = np.linspace(lo, hi, grid)
    errors = [at(float(x)) for x in xs]
    if not np.isfinite(errors).any():
        raise TryonError(f"every simulation across {lo:.3f}..{hi:.3f} failed; nothing to refine")
    i = int(np.argmin(errors))
    a, b = float(xs[max(i - 1, 0)]), float(xs[min(i + 1, grid - 1)])
    c, d = b - INVERSE_PHI * (b - a), a + INVERSE_PHI * (b - a)
    fc = at(c) if golden >= 1 else math.inf
    fd = at(d) if golden >= 2 else math.inf
    for _ in range(golden - 2):
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - INVERSE_PHI * (b - a)
            fc = at(c)
        else:
            a, c, fc = c, d, fd
            d = a + INVERSE_PHI * (b - a)
            fd = at(d)
    best = min(seen, key=lambda s: s[1])
    return best[0], best[1], seen


def misfit(simulated: np.ndarray | None, observed: np.ndarray, size: float) -> float:
    """Mean vertex distance over frames 1.. divided by `size`; inf for a missing or broken simulation."""
    if simulated is None or simulated.shape != observed.shape or not np.isfinite(simulated).all():
        return math.inf
    return float(np.linalg.norm(simulated[1:] - observed[1:], axis=-1).mean() / size)


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

    @property
    def size(self) -> float:
        """The garment's extent in its first frame (the misfit's unit)."""
        return float(np.linalg.norm(self.observed[0].max(0) - self.observed[0].min(0)))

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

    def misfit(self, fabric: WangFabric) -> float:
        """How far the garment simulated in `fabric` is from the observed one (inf if the simulation fails)."""
        if len(self.observed) < 2 or not self.size > 0:
            raise TryonError(f"the observed garment needs at least 2 frames with extent, got {self.observed.shape}")
        try:
            simulated = self.simulate(fabric)
        except SimulationError:
            simulated = None
        return misfit(simulated, self.observed, self.size)


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


def golden_steps(width: float, grid: int = GRID_POINTS, resolution: float = RESOLUTION_LOG10,
                 least: int = GOLDEN_STEPS) -> int:
    """Golden-section points that narrow the bracket a `grid` over `width` (log10) leaves
    (two grid spacings) to `resolution`, and at least `least`: the first two points
    narrow it by 1/phi, each further one by 1/phi again."""
    bracket = 2.0 * width / (grid - 1)
    if bracket <= resolution:
        return least
    return max(least, 1 + math.ceil(math.log(bracket / resolution) / math.log(1.0 / INVERSE_PHI)))


def refine_clip_fabric(clip: ClipToRefine, classes: FabricClasses, c: int, bases: tuple[str, ...] = MEASURED_FABRICS,
                       bounds: tuple[float, float] | None = None, grid: int = GRID_POINTS, golden: int | None = None,
                       progress: Callable[[str], None] | None = None) -> Refinement:
    """The fabric of class c whose simulation follows `clip` best. First the base: each
    measured fabric of `bases` at the class's centre, the one that follows best kept (its
    density, anisotropy and non-linearity: what the class does not say). Then its
    stretching, searched over `bounds` (the class's stretching range by default) with the
    bending at the class's centre: `golden` golden-section points after the grid, by
    default as many as the range's width needs (`golden_steps`)."""
    if not bases:
        raise TryonError("the refinement needs at least one measured fabric to start from")
    (s0, s1), (b0, b1) = classes.box(c)
    inside = EDGE_MARGIN * (s1 - s0)  # float32 features: a fabric right on an edge may read as the neighbour's
    bounds = bounds or (s0 + inside, s1 - inside)
    if not bounds[1] > bounds[0] or grid < 2:
        raise TryonError(f"the search needs a range that rises and at least 2 grid points, got {bounds}, {grid}")
    centre, bend = (s0 + s1) / 2, (b0 + b1) / 2
    golden = golden_steps(bounds[1] - bounds[0], grid) if golden is None else golden
    t0 = time.perf_counter()
    history: list[dict] = []

    def fabric(base: str, s: float) -> WangFabric:
        f = WangFabric.from_preset(base)
        s_base, b_base = classes.position(f)
        return scaled_stiffness(f, 10.0 ** (s - s_base), 10.0 ** (bend - b_base), name=f"{base}-refined")

    def trial(base: str, s: float) -> float:
        error = clip.misfit(fabric(base, s))
        history.append({"base": base, "stretch_log10": s, "error": None if math.isinf(error) else error})
        if progress:
            progress(f"simulation {len(history)}: {base} at stretching 10^{s:.3f} N/m -> misfit {error:.5f}")
        return error

    with torch.no_grad():
        at_centre = {base: trial(base, centre) for base in bases}
        base = min(at_centre, key=lambda b: (at_centre[b], b))
        if math.isinf(at_centre[base]):
            raise TryonError(f"every simulation at the centre of class {classes.name(c)} failed; nothing to refine")
        try:
            s, error, _ = search_scale(lambda x: at_centre[base] if math.isclose(x, centre, abs_tol=1e-9)
                                       else trial(base, x), bounds, grid, golden)
        except TryonError:  # every point of an even grid failed: the centre (not on it) did not
            s, error = centre, math.inf
    if at_centre[base] <= error:
        s, error = centre, at_centre[base]
    refined = fabric(base, s)
    refined.composition = (f"{base} with its stretching refined against a clip and its bending at the centre of "
                           f"fabric class {classes.name(c)}")
    notes = [f"bending kept at the centre of class {classes.name(c)} (10^{bend:.2f} N m): a clip's motion "
             "hardly shows it"]
    half_step = (bounds[1] - bounds[0]) / (grid - 1) / 2
    if min(s - bounds[0], bounds[1] - s) < half_step:
        notes.append(f"the best stretching lies at the end of the searched range (10^{s:.3f} N/m): the fabric is "
                     "likely of a neighbouring class")
    return Refinement(float(s), float(bend), refined, base, at_centre, at_centre[base], error, len(history),
                      time.perf_counter() - t0, history, notes)
