"""`tryon drape`: a garment of a given size and fabric on a body from measurements.

1. Fit Anny to the person's measurements (tryon.body.fit).
2. The size's fit model: Anny fitted to the size chart's girths and stature (or, made to
   measure, the person); the pattern is drafted on the fit model's measurements.
3. Dress the pattern on the fit model in the A-pose (sewn in simulation; cached). A top
   whose sewn sleeves end up through the bodice (a heavy fit model's armpits squeeze
   them together) is dressed again with the arms further out (`DRESS_ARM_ANGLES`); the
   morph then also brings the arms down to the person's A-pose.
4. Simulate: the body morphs from the fit model to the person over `morph_time` (by
   default long enough that no point of the body under the garment moves faster than
   `MORPH_SPEED`)
   (a key-framed collision obstacle); cloth near the skin is carried along with the
   body's change of shape (`SkinBinding`) while gravity, elasticity and contact act, then
   the run continues, with longer steps (`MAX_SETTLE_DT`), until the cloth is at rest
   (static equilibrium: every vertex's mean velocity over the last `REST_WINDOW` steps
   below `rest_speed`) or `max_settle_time`
   passes. The dressed garment must start free of self-crossings (`check_start`); a step that
   flings cloth faster than `PLAUSIBLE_SPEED` is redone from rest in halves (recorded in
   `speed_recoveries`), and `FAILSAFE_STREAK` frozen fail-safe steps in a row, or
   `MAX_FAILSAFE_STEPS` in all, stop the drape with a `SimulationError` naming the
   impacts and vertices it is stuck on.
5. Measure and write: meshes, GLB, renders, fit maps, report.json.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from tryon.body.fit import BodyFit, Measurements, fit_body
from tryon.body.measure import centre_profiles, drafting_measurements, girth_profile, made_to_measure_measurements
from tryon.body.motion import morph_keyframes, smoothstep
from tryon.body.pose import POSES, BodyPose, arm_pose, clear_thighs, named_pose, posed_body
from tryon.errors import SimulationError, TryonError
from tryon.fabric import load_fabric
from tryon.garment.drafts import GARMENTS, WAISTBAND_GARMENTS, BodyCover, draft
from tryon.drape.dress import DressedGarment, cloth_on_body, dress_cached
from tryon.garment.prints import PRINT_WIDTH, GraphicPrint
from tryon.garment.sizes import SIZES, size_measurements
from tryon.sizing.chart import larger_sizes_that_close, too_small_for

log = logging.getLogger(__name__)

STATE_FILE = "drape_state.npz"
# Arm angles (degrees from the body's downward axis) at which a top is dressed on its fit
# model, in order: the A-pose, then wider if the sewn garment still crosses itself (welding
# through a fold at the armpit is smoothed out since: the tops that needed 50 or 60 degrees
# now sew clean at 45; at 60 a long sleeve's first sewing step crawled for minutes).
DRESS_ARM_ANGLES = (POSES["a"], 50.0)
PRINTABLE = ("tshirt", "longsleeve", "dress")  # garments with a front panel
# Trousers pass two layers of cloth between the thighs, each kept a contact thickness from
# the skin and from the other: thighs closer than 2 cm stand further apart for them
# (`clear_thighs`). A 175 cm, 138 kg woman's thighs just cleared each other at 4 degrees
# (4 mm apart): her made-to-measure trousers were dressed through themselves at the
# crotch and their drape ran out of time. At 12 mm its collision response failed from the
# first steps; at 2 cm (7 degrees) it settles. Skirts and dresses hang outside the thighs.
TROUSER_THIGH_GAP = 0.02
DRAPE_SUBSTEP_DEPTH = 1
# Draping a garment is slow motion: gravity over a couple of seconds and a body changing
# shape at well under 1 m/s. A vertex faster than this has been flung by a failed solve or
# collision response: the step is redone from its start, its velocities dropped and dt halved.
PLAUSIBLE_SPEED = 5.0  # m/s
# The rigid fail-safe, as a last resort, freezes the cloth where it was; that many frozen
# fail-safe steps in a row mean the drape cannot make progress (caught in itself or the body).
FAILSAFE_STREAK = 5
FROZEN = 1e-5  # m: a step that moves no vertex farther than this has not moved the cloth
# Each fail-safe step costs tens of seconds (the impact zones grow before the rigid
# fallback). A drape that keeps needing it is a garment the body cannot fill without
# crushing it (a size S T-shirt on a 182 cm, BMI 39 man: 40-80 s per step, 13 minutes in
# all, before this budget); it stops with a diagnosis instead of crawling on.
MAX_FAILSAFE_STEPS = 6
# Static equilibrium is judged on the motion over this many steps (the mean velocity of
# every vertex over that window): a vertex chattering in place against the skin (a hem
# resting on the heel) does not move on, a garment still sliding or swinging does.
REST_WINDOW = 4
# The body changes from the fit model to the person no faster than this (m/s): a faster
# morph pinches cloth between arm and torso and flings it (a thin man in a size S fit
# model's T-shirt: 9 cm of change in 0.4 s flung the sleeves; in 0.6 s it drapes).
MORPH_SPEED = 0.1
MIN_MORPH_TIME, MAX_MORPH_TIME = 0.4, 2.0  # s
# Only the body under the garment sets that pace: the skin within this of the dressed
# garment (a T-shirt's morph does not wait for the feet, nor a skirt's for the hands).
MORPH_NEAR_GARMENT = 0.05  # m
# Still-air damping (1/s) while the garment settles after the morph: a skirt's or a
# dress's hem would otherwise swing on for seconds around the equilibrium it has reached.
SETTLE_AIR_DAMPING = 4.0
# After the morph nothing drives the cloth but gravity: it settles with steps
# `DrapeRequest.settle_dt_ratio` times the morph's (2 by default), up to MAX_SETTLE_DT. The
# implicit step damps the slow modes (a denim dress's flared side creeping at 3-4 cm/s
# after 1.5 s at dt 0.01) and reaches the same rest in fewer steps (the dress: 94 steps
# instead of 190 unsettled, the same strain to 0.01 %).
MAX_SETTLE_DT = 0.02  # s
# With the body's overall move left out, most morphs take the shortest time (0.4 s) and the
# cloth settles after it: denim skirts, dresses, trousers and a T-shirt's sleeve came to
# rest 0.1-0.7 s after 1.5 s of settling (they had settled during 1-2 s morphs before).
# Cloth at rest stops earlier: the limit only bounds a drape that keeps moving.

def morph_duration(start: np.ndarray, target: np.ndarray, requested: float | None = None,
                   near: np.ndarray | None = None) -> float:
    """The morph's duration: `requested`, or the largest displacement of the body vertices
    `near` (a mask; all without it) over `MORPH_SPEED`, within MIN_MORPH_TIME..MAX_MORPH_TIME."""
    if requested is not None:
        return float(requested)
    moved = np.linalg.norm(np.asarray(target) - np.asarray(start), axis=1)
    if near is not None:
        moved = moved[near]
    largest = float(moved.max()) if len(moved) else 0.0
    return float(np.clip(largest / MORPH_SPEED, MIN_MORPH_TIME, MAX_MORPH_TIME))


def body_near_garment(body_vertices: np.ndarray, garment_vertices: np.ndarray, reach: float = MORPH_NEAR_GARMENT) -> np.ndarray:
    """Mask of the body vertices within `reach` of the garment."""
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(garment_vertices).query(body_vertices, distance_upper_bound=reach)
    return np.isfinite(dist)


@dataclass
class DrapeRequest:
    body: Measurements
    garment: str = "tshirt"
    size: str | None = "M"       # None: made to measure on the person's own body
    fabric: str = "gray-interlock"
    edge_length: float = 0.012   # m
    dt: float = 0.01             # s
    morph_time: float | None = None  # s; None: the largest displacement of the body under the garment / MORPH_SPEED
    max_settle_time: float = 3.0  # s (the note under MAX_SETTLE_DT)
    rest_speed: float = 0.02     # m/s
    thickness: float = 0.004     # m, contact distance kept from the skin
    friction: float = 0.4        # skin-cloth Coulomb coefficient once the body has its shape
    morph_friction: float = 0.0  # while the body morphs the cloth slides (as when putting it on)
    print_image: str | None = None  # a PNG printed on the front panel (tryon.garment.prints)
    print_width_cm: float = 100 * PRINT_WIDTH
    allow_tight: bool = False    # drape a size far too small for the body (to see how it strains) instead of refusing it
    settle_dt_ratio: float = 2.0  # after the morph: steps this many times dt (at most MAX_SETTLE_DT; module notes)
    morph_whole_body: bool = False  # pace the morph by every body vertex, not only those under the garment
    time_limit_s: float = 600.0  # wall-clock budget of the simulated drape (after dressing); past it, the drape stops after the step in progress, with a diagnosis

    def graphic_print(self, garment: DressedGarment) -> GraphicPrint | None:
        """The print placed on `garment`'s front panel (None without `print_image`)."""
        if self.print_image is None:
            return None
        if garment.pattern is None:
            raise TryonError("a print goes on a drafted garment's front panel; an OBJ garment has no panels")
        return GraphicPrint.load(self.print_image, self.print_width_cm).placed_on(garment.pattern)

    def material_regions(self, garment: DressedGarment) -> list:
        """What the simulator models beyond the fabric: the print's `MaterialRegion`, if any."""
        pr = self.graphic_print(garment)
        return [] if pr is None else [pr.region(garment)]

    @property
    def garment_obj(self) -> Path | None:
        """The garment OBJ file when `garment` names one (tryon.drape.obj_garment)."""
        return Path(self.garment) if self.garment.lower().endswith(".obj") else None

    def validate(self) -> None:
        if self.garment_obj is not None:
            if not self.garment_obj.is_file():
                raise TryonError(f"garment OBJ {self.garment_obj} does not exist")
        elif self.garment not in GARMENTS:
            raise TryonError(f"unknown garment {self.garment!r}; available: {', '.join(GARMENTS)}, or a garment .obj")
        if self.size is not None and self.size.upper() not in SIZES:
            raise TryonError(f"unknown size {self.size!r}; standard sizes: {', '.join(SIZES)} (or made-to-measure)")
        if not 0.004 <= self.edge_length <= 0.05:
            raise TryonError(f"edge length {self.edge_length} m is outside 0.004-0.05 m")
        if not 0.001 <= self.dt <= 1 / 30:
            raise TryonError(f"time step {self.dt} s is outside 0.001-0.033 s")
        if not 1.0 <= self.settle_dt_ratio <= 4.0:
            raise TryonError(f"settle step ratio {self.settle_dt_ratio} is outside 1-4")
        if not self.time_limit_s > 0.0:
            raise TryonError(f"time limit {self.time_limit_s} s must be positive")
        if self.morph_time is not None and not 0.0 < self.morph_time <= 10.0:
            raise TryonError(f"morph time {self.morph_time} s is outside 0-10 s")
        load_fabric(self.fabric)  # raises FabricError naming the presets
        if self.print_image is not None:
            if self.garment_obj is not None or self.garment not in PRINTABLE:
                raise TryonError(f"a print goes on a front panel: garments {', '.join(PRINTABLE)}, not {self.garment}")
            GraphicPrint.load(self.print_image, self.print_width_cm)  # raises naming what is wrong with the file
        self.body.validate()


@dataclass
class DrapeResult:
    request: DrapeRequest
    person: BodyFit
    fit_model: BodyFit | None
    garment: DressedGarment
    body_vertices: np.ndarray        # the person in the A-pose
    body_faces: np.ndarray
    x: np.ndarray                    # draped garment vertices
    frames: list[np.ndarray] = field(default_factory=list)
    frame_times: list[float] = field(default_factory=list)
    metrics: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


def fit_model_measurements(request: DrapeRequest) -> Measurements | None:
    """The fit model of a standard size: the size chart's girths at its stature."""
    if request.size is None or request.garment_obj is not None:
        return None
    s = size_measurements(request.size, request.body.gender)
    return Measurements(height_cm=s["height_cm"], gender=request.body.gender, chest_cm=s["chest_cm"],
                        waist_cm=s["waist_cm"], hip_cm=s["hip_cm"], age=request.body.age)


class SkinBinding:
    """Each garment vertex bound to its nearest point on the body (face + barycentrics),
    with a weight that fades from 1 within `near` of the skin to 0 beyond `far`; `motion`
    gives the body's displacement at those points, so cloth near the skin can be carried
    along with a changing body while loose cloth is left to physics."""

    def __init__(self, x: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray, near: float = 0.02, far: float = 0.08):
        from tryon.sim.geometry import nearest_surface_locations

        dist, self.face, self.bary = nearest_surface_locations(x, body_vertices, body_faces)
        self.corners = body_faces[self.face]
        self.weight = np.clip((far - dist) / (far - near), 0.0, 1.0)

    def points(self, body_vertices: np.ndarray) -> np.ndarray:
        return np.einsum("nk,nkd->nd", self.bary, body_vertices[self.corners])

    def motion(self, body_from: np.ndarray, body_to: np.ndarray) -> np.ndarray:
        return self.weight[:, None] * (self.points(body_to) - self.points(body_from))


def _where(x: np.ndarray, verts: np.ndarray, limit: int = 5) -> str:
    """A few vertex ids with their positions (cm), for error messages."""
    verts = np.asarray(verts)[:limit]
    return ", ".join(f"{int(v)} at ({', '.join(f'{100 * c:.1f}' for c in x[v])}) cm" for v in verts)


def check_start(x: np.ndarray, faces: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray, what: str) -> int:
    """Collision handling keeps a garment free of crossings only if it starts free of them:
    a dressed garment through itself cannot drape (every step would end in the fail-safe),
    so it is refused here with the crossing vertices named. Coarse cloth edges through
    the skin (at the neck, say) are pushed out by the contact forces: their number is
    returned, for the report."""
    from tryon.sim.geometry import mesh_edges
    from tryon.sim.geometry import edge_face_intersections

    e = mesh_edges(faces)
    own = edge_face_intersections(x, e, x, faces, True)
    if len(own):
        verts = np.unique(np.concatenate([e[own[:, 0]].ravel(), faces[own[:, 1]].ravel()]))
        raise SimulationError(
            f"{what} starts crossing itself at {len(own)} edge-triangle pairs ({len(verts)} vertices, e.g. "
            f"{_where(x, verts)}); it cannot be draped from there")
    return len(edge_face_intersections(x, e, body_vertices, body_faces, False))


def stall_diagnosis(solver, x: np.ndarray) -> str:
    """What the last collision response was stuck on: its impacts by kind, its impact
    zones and the cloth vertices most often involved."""
    rep = getattr(solver, "last_collision", None)
    if rep is None or len(rep.constraints) == 0:
        return "no impacts recorded"
    idx = rep.constraints.idx
    cloth = idx[idx >= 0]
    verts, count = np.unique(cloth, return_counts=True)
    top = verts[np.argsort(-count)]
    kinds = ", ".join(f"{n} {k}" for k, n in rep.constraints.counts().items() if n)
    lo, hi = x[verts].min(0), x[verts].max(0)
    return (f"{len(rep.constraints)} impacts ({kinds}) in {rep.zones} zones over {len(verts)} vertices, "
            f"between ({', '.join(f'{100 * c:.0f}' for c in lo)}) and ({', '.join(f'{100 * c:.0f}' for c in hi)}) cm; "
            f"most involved: {_where(x, top)}")


def over_time_diagnosis(name: str, limit: float, state, stats: dict, drift: float, speeds: np.ndarray, stall: str) -> str:
    """Why a drape ran past its time limit: how far it got, how fast it still moves,
    where, and what its steps cost (fail-safe and retried steps, the slowest step)."""
    x = state.x.numpy()
    moving = "its speed of drift not yet measured" if not np.isfinite(drift) else f"drifting at {drift:.3f} m/s"
    return (f"draping {name} ran past its time limit of {limit:g} s at t={state.t:.2f}s after {stats['steps']} steps, "
            f"{moving}, fastest {speeds.max():.3f} m/s at {_where(x, np.argsort(-speeds), 3)}; "
            f"{stats['failsafe_steps']} fail-safe and {stats['retried_steps']} retried steps, slowest step "
            f"{stats['max_step_s']:.1f} s; last collision response: {stall} (a slower machine may need a larger "
            f"--time-limit)")


def waistband_vertices(garment: DressedGarment) -> np.ndarray:
    """The vertices of the waist opening of garments hung from the waist (trousers,
    skirts): the highest boundary loop. Empty for other garments."""
    if garment.pattern is None or garment.pattern.meta.get("garment", garment.pattern.name) not in WAISTBAND_GARMENTS:
        return np.zeros(0, np.int64)
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    f = garment.faces
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), 1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    b = uniq[count == 1]
    n = len(garment.vertices)
    _, labels = connected_components(sp.coo_matrix((np.ones(len(b)), (b[:, 0], b[:, 1])), shape=(n, n)), directed=False)
    verts = np.unique(b)
    loops = [verts[labels[verts] == k] for k in np.unique(labels[verts])]
    return max(loops, key=lambda v: garment.vertices[v, 2].mean())


def waistband_pin(garment: DressedGarment, frames: np.ndarray, times: np.ndarray, body_faces: np.ndarray):
    """A waistband holds trousers and skirts up (as a belt or a fitted band does): its
    vertices are pinned to the skin under them, following the body while it changes shape."""
    from tryon.sim.model import PinGroup
    from tryon.sim.obstacles import Motion

    verts = waistband_vertices(garment)
    if len(verts) == 0:
        return []
    x = garment.vertices[verts]
    bind = SkinBinding(x, frames[0], body_faces, near=1.0, far=2.0)  # weight 1: carried fully
    keys = np.stack([x + bind.points(fr) - bind.points(frames[0]) for fr in frames])
    return [PinGroup(torch.from_numpy(verts), Motion(keyframes=keys, keyframe_times=np.asarray(times)))]


def simulate_drape(request: DrapeRequest, garment: DressedGarment, start: BodyPose, target: BodyPose,
                   progress: bool = True) -> tuple[np.ndarray, list, list, dict, object]:
    """Morph the body from `start` to `target` under the dressed garment, then settle."""
    from tryon.sim.geometry import push_outside
    from tryon.sim.integrator import ImplicitEulerSolver, StepOptions
    from tryon.sim.loop import FailSafeLimit, FlungRedo, FrameRecorder, RestDrift, StepLog, TimeLimit, TopSpeed, run
    from tryon.sim.model import Control
    from tryon.sim.obstacles import Motion, Obstacle

    fabric = load_fabric(request.fabric)
    near, shift = None, np.zeros(3)
    if not request.morph_whole_body:
        near = body_near_garment(start.vertices, garment.vertices)
        if near.any():  # the body under the garment moves as a whole by `shift`: simulated without it
            shift = (target.vertices - start.vertices)[near].mean(axis=0)
    morph_time = morph_duration(start.vertices, target.vertices - shift, request.morph_time, near)
    frames, times = morph_keyframes(start.vertices, target.vertices - shift, morph_time)
    body = Obstacle("body", start.vertices, start.faces, Motion(keyframes=frames, keyframe_times=times))
    model = cloth_on_body(garment.cloth_mesh(), fabric, body, request.thickness, friction=request.friction,
                          pins=waistband_pin(garment, frames, times, start.faces), regions=request.material_regions(garment))
    # while the body morphs the cloth slides (as when putting it on), then it holds and
    # settles in still air (a hem's swing dies out; the static equilibrium is the same)
    morphing, holding = Control(friction=request.morph_friction), Control(air_damping=SETTLE_AIR_DAMPING)
    # a failing step is split once, then its impact zones are made rigid: on a garment
    # far too small for the body, deeper splitting only repeats the same infeasible zones
    solver = ImplicitEulerSolver(model, StepOptions(max_substep_depth=DRAPE_SUBSTEP_DEPTH))
    state = model.initial_state()
    binding = SkinBinding(state.x.numpy(), start.vertices, start.faces)
    start_crossings = check_start(state.x.numpy(), garment.faces, start.vertices, start.faces,
                                  f"the dressed {garment.name}")
    settle_dt = max(request.dt, min(request.settle_dt_ratio * request.dt, MAX_SETTLE_DT))

    def carried(k: int, s):  # the cloth near the skin is carried with the changing body, physics does the rest
        if s.t >= morph_time:
            return s
        now = model.obstacles.vertices_at(s.t)
        x = s.x.numpy() + binding.motion(model.obstacles.vertices_at(s.t - request.dt), now)
        x, _, _ = push_outside(x, now, start.faces, request.thickness)
        return type(s)(torch.from_numpy(x), s.v, s.t)

    log, top = StepLog(), TopSpeed()
    rest = RestDrift(REST_WINDOW, request.rest_speed, after_t=morph_time)
    recorder = FrameRecorder(every=4, last=-1, first=state)

    def flung_why(before, redone, speeds) -> str:
        return (f"draping {garment.name}: at t={before.t:.2f}s the cloth moves at {speeds.max():.1f} m/s even after "
                f"redoing the step in halves from rest (at most {PLAUSIBLE_SPEED} m/s is plausible); fastest "
                f"{_where(redone.x.numpy(), np.argsort(-speeds))}; {stall_diagnosis(solver, redone.x.numpy())}")

    def stuck_why(kind: str, rec, count: int) -> str:
        stall = stall_diagnosis(solver, rec.state.x.numpy())
        if kind == "streak":
            return (f"draping {garment.name} makes no progress: at t={rec.state.t:.2f}s the collision response has "
                    f"failed {count} steps in a row and the rigid fail-safe froze the cloth; {stall}")
        hint = (f"is size {request.size} far too small for this body?" if request.size else
                "does the body leave the garment room, between the thighs or under the arms?")
        return (f"draping {garment.name} makes no progress: by t={rec.state.t:.2f}s the collision response has failed "
                f"in {count} steps and needed the rigid fail-safe (the body presses the cloth into itself; {hint}); "
                f"{stall}")

    def counts() -> dict:
        return {"steps": log.steps, "retried_steps": log.retried, "failsafe_steps": log.failsafe,
                "speed_recoveries": log.flung, "max_step_s": log.slowest_s, "max_speed": top.fastest}

    def over_time(rec) -> str:
        return over_time_diagnosis(garment.name, request.time_limit_s, rec.state, counts(), rest.drift, top.speeds,
                                   stall_diagnosis(solver, rec.state.x.numpy()))

    outcome = run(solver, state, lambda k, t: request.dt if t < morph_time else settle_dt, until=None,
                  until_time=morph_time + request.max_settle_time,
                  observers=[FailSafeLimit(MAX_FAILSAFE_STEPS, FAILSAFE_STREAK, FROZEN, explain=stuck_why), log, recorder,
                             top, rest],
                  control=lambda k, t: morphing if t < morph_time else holding, before_step=carried,
                  redo_flung=FlungRedo(PLAUSIBLE_SPEED, explain=flung_why),
                  time_limit=TimeLimit(request.time_limit_s, explain=over_time),
                  progress="draping" if progress else None,
                  total=int(np.ceil(morph_time / request.dt + request.max_settle_time / settle_dt)))
    state = outcome.state
    out_frames, out_times = recorder.positions, recorder.times
    if out_times[-1] != state.t:
        out_frames.append(state.x.numpy().copy())
        out_times.append(state.t)
    # back to the person's place: each frame moved as far as the body had moved by then
    moved = np.interp(out_times, times, smoothstep(np.linspace(0.0, 1.0, len(times))))
    out_frames = [f + w * shift for f, w in zip(out_frames, moved)]
    stats = counts()
    stats["start_body_crossings"] = start_crossings
    stats.update({"substeps": outcome.totals.substeps, "seconds": outcome.totals.seconds})
    stats.update({"simulated_s": state.t, "morph_s": morph_time, "settled": rest.settled,
                  "final_max_speed": float(np.linalg.norm(state.v.numpy(), axis=1).max()), "final_rest_speed": rest.drift})
    stats["body_shift_m"] = shift.tolist()
    return state.x.numpy() + shift, out_frames, out_times, stats, solver


def check_size_fits(request: DrapeRequest, person: BodyFit) -> None:
    """Refuse a standard size far too small for the person (`size_too_small`) unless
    `allow_tight` asks to see it strain."""
    if request.size is None or request.garment_obj is not None or request.allow_tight:
        return
    size = request.size.upper()
    why = too_small_for(request.garment, size, request.body.gender, person.achieved)
    if why is not None:
        bigger = larger_sizes_that_close(request.garment, size, request.body.gender, person.achieved)
        hint = f"try size {bigger[0]}" if bigger else "no standard size is large enough: use --size made-to-measure"
        raise TryonError(f"{why}; {hint} (or --allow-tight to drape it anyway and see the strain)")


def thigh_gap_for(garment: str) -> float:
    """How far apart (m) the thighs stand for a garment (`TROUSER_THIGH_GAP`)."""
    return TROUSER_THIGH_GAP if garment == "trousers" else 0.0


def drape_pose(shape, garment: str) -> np.ndarray:
    """The A-pose a drape of `garment` stands in (thighs `thigh_gap_for` it apart): what
    the drape's body is, and where an animation of the drape starts."""
    return named_pose(shape, "a", thigh_gap_for(garment))


def made_to_measure_cover(shape, m: dict) -> BodyCover:
    """What a made-to-measure skirt or dress must pass over: the body's girths from its
    waist down to the knee, and its front and back from the neck down to the knee."""
    return BodyCover(*girth_profile(shape, m["knee_height"], m["waist_height"]),
                     *centre_profiles(shape, m["knee_height"] - 0.2, m["neck_height"] + 0.05))


def dress_on_fit_model(pattern, shape, crotch_height: float, fabric, edge_length: float,
                       progress: bool = True, thigh_gap: float = 0.0,
                       a_pose: np.ndarray | None = None) -> tuple[BodyPose, DressedGarment]:
    """The fit model's pose and the garment dressed on it: in the A-pose (thighs at least
    `thigh_gap` apart; `a_pose`: those rotations when already found), or, for a garment with
    sleeves, with the arms further out when the garment sewn there crosses itself
    (`DRESS_ARM_ANGLES`)."""
    sleeved = any(p.placement.get("part") == "arm" for p in pattern.panels)
    angles = DRESS_ARM_ANGLES if sleeved else DRESS_ARM_ANGLES[:1]
    for angle in angles:
        if angle == POSES["a"] and a_pose is not None:
            R = a_pose
        else:
            R = clear_thighs(shape, arm_pose(shape, angle), thigh_gap)[0]
        start = posed_body(shape, R, crotch_height)
        garment = dress_cached(pattern, start, fabric, edge_length, progress=progress)
        garment.stats["dress_arm_angle_deg"] = angle
        if garment.stats.get("self_intersections", 0) == 0:
            break
        if angle != angles[-1]:
            log.warning("dressing %s again with the arms further out (%d crossings at %.0f degrees)", pattern.name,
                        garment.stats["self_intersections"], angle)
    return start, garment


def drape(request: DrapeRequest, progress: bool = True, person: BodyFit | None = None) -> DrapeResult:
    """Run the whole try-on; see the module docstring. Outputs are written by `write_outputs`.
    `person`: drape on this fitted body instead of fitting `request.body` (e.g. a dataset's
    pinned body, `fit_body(..., prior=False)`)."""
    request.validate()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    person = person or fit_body(request.body)
    timings["fit_body_s"] = time.perf_counter() - t0
    check_size_fits(request, person)
    fm_meas = fit_model_measurements(request)
    t1 = time.perf_counter()
    # the size chart's fit model stays Anny's average shape of the chart (pinned: every
    # standard-size pattern, the learned drapes and their datasets are drafted on it)
    fit_model = fit_body(fm_meas, prior=False) if fm_meas is not None else None
    timings["fit_model_s"] = time.perf_counter() - t1
    model_shape = (fit_model or person).shape
    # made to measure: drafted on the wearer's body with its tape crotch height
    made_to_measure = fit_model is None and request.garment_obj is None
    pm = (made_to_measure_measurements if made_to_measure else drafting_measurements)(person.shape)
    target_pose = drape_pose(person.shape, request.garment)
    target = posed_body(person.shape, target_pose, pm["crotch_height"])
    t2 = time.perf_counter()
    if request.garment_obj is not None:  # already around the person: nothing to morph
        from tryon.drape.obj_garment import garment_from_obj

        start = target
        garment = garment_from_obj(request.garment_obj, target, clearance=request.thickness + 0.002)
    else:
        m = pm if made_to_measure else drafting_measurements(model_shape)
        pattern = draft(request.garment, m, size=request.size.upper() if request.size else "made-to-measure",
                        meta={"gender": request.body.gender}, cover=made_to_measure_cover(person.shape, m) if made_to_measure else None)
        if request.print_image is not None:  # a print that does not fit is refused before dressing
            GraphicPrint.load(request.print_image, request.print_width_cm).placed_on(pattern)
        start, garment = dress_on_fit_model(pattern, model_shape, m["crotch_height"], load_fabric(request.fabric),
                                            request.edge_length, progress, thigh_gap_for(request.garment),
                                            a_pose=target_pose if model_shape is person.shape else None)
    timings["dress_s"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    x, frames, times, stats, solver = simulate_drape(request, garment, start, target, progress=progress)
    timings["simulate_s"] = time.perf_counter() - t3
    result = DrapeResult(request, person, fit_model, garment, target.vertices, target.faces, x, frames, times, timings=timings)
    t4 = time.perf_counter()
    from tryon.drape.fit_metrics import drape_metrics

    result.metrics = drape_metrics(result, solver, body_shift=np.asarray(stats["body_shift_m"]))
    result.metrics.update(stats)
    timings["metrics_s"] = time.perf_counter() - t4
    timings["wall_s"] = time.perf_counter() - t0
    return result


def save_state(result: DrapeResult, path: Path) -> None:
    """What `tryon animate` needs to continue from a drape."""
    from tryon.io.atomic import atomic_write

    g = result.garment
    req = asdict(result.request)
    with atomic_write(path, "wb") as fh:
        np.savez_compressed(fh, x=result.x, faces=g.faces, uv=g.uv, corner_uv=g.corner_uv, face_panel=g.face_panel,
                            body_vertices=result.body_vertices, body_faces=result.body_faces,
                            body_params=json.dumps(result.person.params.to_dict()), request=json.dumps(req),
                            pattern=json.dumps(g.pattern.to_dict() if g.pattern is not None else {"name": g.name}))


def load_state(path: Path) -> dict:
    if not path.exists():
        raise TryonError(f"{path.parent} holds no drape ({path.name} missing); run `tryon drape ... --out {path.parent}` first")
    from tryon.io.npz import read_npz

    out = read_npz(path, "drape state")
    try:
        for k in ("body_params", "request", "pattern"):
            out[k] = json.loads(str(out[k]))
        n, f = len(out["x"]), len(out["faces"])
        ok = (out["x"].shape == (n, 3) and out["faces"].shape == (f, 3) and out["faces"].min() >= 0
              and out["faces"].max() < n and out["corner_uv"].shape == (f, 3, 2) and np.isfinite(out["x"]).all())
    except (KeyError, ValueError, TypeError) as exc:
        raise TryonError(f"{path} is not a drape state ({exc}); run `tryon drape` again") from exc
    if not ok:
        raise TryonError(f"{path}: the garment arrays do not fit together; run `tryon drape` again")
    return out


def torch_x(x: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(x))
