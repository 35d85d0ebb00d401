"""Pose datasets: one garment on one body, simulated through many pose sequences (for the
KDSM and its pixel-based baseline, tryon.kdsm).

`prepare` drapes the garment of the size on the size's fit model in the A-pose (the
drape every sequence starts from, the KDSM's rest state) and keeps it in `rest.npz`. A
unit is one sequence of `frames` poses at 30 fps (`tryon.body.pose_sampling`): half of
them a built-in motion at a random speed and swing, half random key poses within joint
limits. The body blends from the A-pose into the first pose over `blend_time`, then plays
the sequence `slow` times slower than real time, while the simulator (contact, friction,
self-collision, still-air damping) carries the cloth along; the cloth is recorded at
every pose. Played slowly and damped, the cloth stays near its static equilibrium for
each pose (quasi-static, as Jin et al. 2020 generate theirs), with the hysteresis of
real cloth kept. With `settle` > 0 the body also holds every pose that long before the
cloth is recorded, so the cloth comes to rest in it (the recorded `cloth_speed`, the
cloth's fastest vertex at each pose, tells how far it did). With `from_rest` every pose
is simulated on its own from the rest drape instead: the body blends from the A-pose into
that pose over `blend_time`, holds it `settle` seconds, and the cloth is recorded. The
cloth is then a function of the pose alone: carried through a sequence, friction keeps
what the path did (arm-raise poses reached in two sequences hold cloth 1.2 cm apart,
median; the pair furthest apart, 3.2 cm, comes out 0.35 cm apart from rest), which no
pose-to-cloth network can learn. A sequence
the simulator cannot carry (flung cloth, a pinch it stalls on) is kept with `ok` false
and its message.

Splits are by sequence (train / val / test at 8:1:1, drawn per unit from the seed), so no
test pose has a training neighbour a frame away.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tryon.dataset.store import DatasetError, Manifest, ShardStore, sample_rows
from tryon.errors import TryonError

KIND = "poses"
GENERATOR_VERSION = 1
SOURCES = ("walk", "arm-raise", "turn", "random")
SOURCE_WEIGHTS = (1 / 6, 1 / 6, 1 / 6, 1 / 2)
FPS = 30.0
REST_FILE = "rest.npz"
PLAUSIBLE_SPEED = 5.0  # m/s, as the drape's
KEY_SPACING = 15  # frames between random key poses (half a second of motion)
# A pose that pinches cloth the collision response cannot free needs the rigid fail-safe,
# step after step, each costing seconds; the sequence is given up after this many.
MAX_FAILSAFE_STEPS = 3
FROM_REST_SETTLE = 0.3  # s a pose is held when simulated from rest for a spec without holds


class SequenceFailed(TryonError):
    """The simulator could not carry the cloth through a pose (flung, or pinched)."""


@dataclass
class PoseDatasetSpec:
    """`count` sequences of `frames` poses of the garment of `size` on its fit model."""

    garment: str = "tshirt"
    size: str = "M"
    gender: str = "female"
    fabric: str = "gray-interlock"
    edge_length: float = 0.015
    count: int = 300
    frames: int = 32
    slow: float = 2.0
    blend_time: float = 0.5
    settle: float = 0.0  # s the body holds each pose before the cloth is recorded (0: recorded in passing)
    from_rest: bool = False  # every pose simulated on its own from the rest drape (no history)
    seed: int = 0
    shard_size: int = 16
    train_fraction: float = 0.8
    val_fraction: float = 0.1

    def validate(self) -> None:
        from tryon.fabric import load_fabric
        from tryon.garment.sizes import SIZES

        if self.garment not in ("tshirt", "longsleeve", "dress"):
            raise TryonError(f"pose datasets dress tops and dresses (tshirt, longsleeve, dress), not {self.garment!r}")
        if self.size.upper() not in SIZES or self.gender not in ("female", "male"):
            raise TryonError(f"size {self.size!r} / gender {self.gender!r}: give a standard size and female or male")
        if not 1 <= self.count <= 100_000 or not 2 <= self.frames <= 300:
            raise TryonError(f"--count {self.count} (1-100,000 sequences) or --frames {self.frames} (2-300) out of range")
        if not 0.006 <= self.edge_length <= 0.05 or not 1.0 <= self.slow <= 10.0 or not 0.0 < self.blend_time <= 5.0:
            raise TryonError("edge length 0.006-0.05 m, slow 1-10 and blend time 0-5 s")
        if not 0.0 <= self.settle <= 2.0:
            raise TryonError(f"--settle {self.settle}: hold each pose 0-2 s")
        if self.from_rest and self.settle <= 0.0:
            raise TryonError("--from-rest needs --settle > 0: the cloth is recorded at the end of each pose's hold")
        if not 1 <= self.shard_size <= 4096:
            raise TryonError(f"shard size {self.shard_size} is outside 1-4096 sequences")
        if self.seed < 0:
            raise TryonError(f"--seed {self.seed}: give a seed >= 0")
        load_fabric(self.fabric)

    def manifest(self, software_version: str) -> Manifest:
        self.validate()
        spec = {"garment": self.garment, "size": self.size.upper(), "gender": self.gender, "fabric": self.fabric,
                "edge_length": self.edge_length, "frames": self.frames, "fps": FPS, "slow": self.slow,
                "blend_time": self.blend_time, "sources": list(SOURCES), "source_weights": list(SOURCE_WEIGHTS),
                "drape": {"dt": 0.01, "thickness": 0.004, "friction": 0.4, "air_damping": 4.0}}
        if self.settle > 0:  # only then: datasets made without holds keep their manifests
            spec["settle"] = self.settle
        if self.from_rest:
            spec["from_rest"] = True
        split = {"rule": "by sequence: train / val / test drawn per unit from the seed", "train": self.train_fraction,
                 "val": self.val_fraction}
        return Manifest(KIND, GENERATOR_VERSION, software_version, self.seed, self.count, self.shard_size, spec, split,
                        created=time.strftime("%Y-%m-%dT%H:%M:%S%z"))


def split_of(manifest: Manifest, unit: int) -> str:
    r = np.random.default_rng([manifest.seed, unit, 7]).random()
    rule = manifest.split
    return "train" if r < rule["train"] else "val" if r < rule["train"] + rule["val"] else "test"


@dataclass
class RestDrape:
    """The garment at rest on the body in the A-pose: what every sequence starts from."""

    garment: object          # DressedGarment, vertices = the rest drape
    params: object           # ShapeParams of the body

    def shape(self):
        from tryon.body.anny_model import body_model

        return body_model().rest_shape(self.params).detached()

    def save(self, folder: Path) -> None:
        """rest.json first, rest.npz last (both atomic): rest.npz's presence means both are there."""
        from tryon.io.atomic import atomic_write

        with atomic_write(folder / "rest.json") as fh:
            fh.write(json.dumps({"params": self.params.to_dict()}))
        self.garment.save(folder / REST_FILE)

    @classmethod
    def from_drape(cls, state: dict, shape) -> "RestDrape":
        """The rest state of a `tryon drape` folder (its loaded state): that drape on its body (`shape`)."""
        from tryon.drape.dress import DressedGarment

        return cls(DressedGarment.from_state(state), shape.params)

    @classmethod
    def load(cls, folder: Path) -> "RestDrape":
        from tryon.body.anny_model import ShapeParams
        from tryon.drape.dress import DressedGarment

        if not ((folder / REST_FILE).exists() and (folder / "rest.json").exists()):
            raise DatasetError(f"{folder} holds no rest drape ({REST_FILE}); run `tryon dataset poses` again to make it")
        meta = json.loads((folder / "rest.json").read_text())
        return cls(DressedGarment.load(folder / REST_FILE), ShapeParams.from_dict(meta["params"]))


def prepare(manifest: Manifest, folder: Path, progress: bool = True) -> RestDrape:
    """Drape the garment on the size's fit model in the A-pose (once; kept in the folder)."""
    if (folder / REST_FILE).exists() and (folder / "rest.json").exists():
        return RestDrape.load(folder)
    from tryon.body.fit import Measurements
    from tryon.body.pose import posed_body
    from tryon.dataset.drapes import size_pattern
    from tryon.drape.dress import dress_cached
    from tryon.drape.pipeline import DrapeRequest, simulate_drape
    from tryon.fabric import load_fabric
    from tryon.garment.triangulate import triangulate_pattern

    spec = manifest.spec
    if progress:
        print(f"rest drape: {spec['garment']} {spec['size']} on the {spec['gender']} fit model", flush=True)
    fit, m, pattern = size_pattern(spec["garment"], spec["gender"], spec["size"])
    start = posed_body(fit.shape, "a", m["crotch_height"])
    garment = dress_cached(pattern, start, load_fabric(spec["fabric"]), spec["edge_length"], progress=False,
                           mesh=triangulate_pattern(pattern, spec["edge_length"]))
    # simulate_drape reads the request's drape settings only; the body is `start` itself
    req = DrapeRequest(Measurements(height_cm=170, weight_kg=70, gender=spec["gender"]), garment=spec["garment"],
                       size=spec["size"], fabric=spec["fabric"], edge_length=spec["edge_length"], max_settle_time=1.5,
                       settle_dt_ratio=1.0)  # as this generator's version 1 settled its rest drape
    x, _, _, stats, _ = simulate_drape(req, garment, start, start, progress=False)
    if not stats["settled"]:
        raise DatasetError(f"the {spec['garment']} {spec['size']} does not come to rest on its fit model "
                           f"(still moving at {stats['final_rest_speed']:.3f} m/s)")
    garment.vertices = x
    rest = RestDrape(garment, fit.params)
    folder.mkdir(parents=True, exist_ok=True)
    rest.save(folder)
    return rest


def sequence_poses(manifest: Manifest, shape, unit: int) -> tuple[np.ndarray, dict]:
    """The unit's poses [F,J,3,3] and what was drawn (source, speed, swing)."""
    from tryon.body.pose_sampling import keyframed_poses, varied_motion

    spec = manifest.spec
    rng = np.random.default_rng([manifest.seed, unit])
    source = SOURCES[int(rng.choice(len(SOURCES), p=np.asarray(spec["source_weights"])))]
    if source == "random":
        keys = 1 + max(1, round((spec["frames"] - 1) / KEY_SPACING))
        return keyframed_poses(shape, rng, spec["frames"], spec["fps"], keys=keys), \
            {"motion": "random", "speed": 1.0, "amplitude": 1.0, "start_s": 0.0}
    return varied_motion(shape, source, rng, spec["frames"], spec["fps"])


def step_size(spec: dict) -> float:
    """The time step: the drape's, shortened so that every pose falls on a step (the cloth
    is recorded exactly when the body is in the pose, not between poses)."""
    spacing = spec["slow"] / spec["fps"]
    return spacing / max(1, int(np.ceil(spacing / spec["drape"]["dt"] - 1e-9)))


def settle_time(spec: dict) -> float:
    """How long the body holds each pose (a whole number of steps; 0 without holds)."""
    hold = float(spec.get("settle", 0.0))
    dt = step_size(spec)
    return dt * max(1, round(hold / dt)) if hold > 0 else 0.0


def body_keyframes(shape, poses: np.ndarray, spec: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body vertices per keyframe [K,V,3], their simulated times [K] (the poses' on steps
    of `step_size`), and which keyframes are the sequence's poses, where the cloth is
    recorded (the rest blend from the A-pose into the first; with `settle`, every pose is
    a keyframe twice, at the start and at the end of its hold, and recorded at the end)."""
    from tryon.body.motion import slerp_poses, smoothstep
    from tryon.body.pose import bone_transforms, named_pose, skin

    verts = shape.vertices.detach()
    start = named_pose(shape, "a")
    n_blend = max(1, int(round(spec["blend_time"] * spec["fps"])))
    dt = step_size(spec)
    blend_end = dt * round(spec["blend_time"] / dt)
    hold, spacing = settle_time(spec), spec["slow"] / spec["fps"]
    per_pose = 2 if hold else 1  # keyframes per pose: its arrival, and the end of its hold
    rots = [slerp_poses(start, poses[0], float(smoothstep(k / n_blend))) for k in range(n_blend)]
    rots += [R for R in poses for _ in range(per_pose)]
    frames = np.stack([skin(verts, shape.weight_index, shape.weight, bone_transforms(shape, R)).numpy() for R in rots])
    arrivals = blend_end + np.arange(len(poses)) * (spacing + hold)
    times = np.concatenate([np.arange(n_blend) * blend_end / n_blend,
                            (arrivals[:, None] + np.array([0.0, hold])[:per_pose]).reshape(-1)])
    return frames, times, n_blend + per_pose - 1 + per_pose * np.arange(len(poses))


def pose_unit(manifest: Manifest, rest: RestDrape, unit: int) -> dict[str, np.ndarray]:
    """One sequence as a flat dict of arrays."""
    from tryon.body.pose import matrix_to_axis_angle

    t0 = time.perf_counter()
    spec = manifest.spec
    shape = rest.shape()
    poses, drawn = sequence_poses(manifest, shape, unit)
    F, n = len(poses), len(rest.garment.vertices)
    out = {"split": np.asarray(split_of(manifest, unit)), "source": np.asarray(drawn["motion"]),
           "speed": np.asarray(drawn["speed"]), "amplitude": np.asarray(drawn["amplitude"]),
           "pose": matrix_to_axis_angle(poses).astype(np.float32), "ok": np.asarray(True), "error": np.asarray(""),
           "x": np.full((F, n, 3), np.nan, np.float32), "penetration_pct": np.full(F, np.nan), "max_speed": np.asarray(0.0),
           "cloth_speed": np.full(F, np.nan, np.float32)}
    chains = [slice(k, k + 1) for k in range(F)] if spec.get("from_rest") else [slice(0, F)]
    try:
        for chain in chains:
            simulate_poses(spec, rest, shape, poses[chain], out, chain.start)
    except SequenceFailed as exc:
        out.update({"ok": np.asarray(False), "error": np.asarray(str(exc)[:500])})
    out["wall_s"] = np.asarray(time.perf_counter() - t0)
    return out


def from_rest_spec(spec: dict) -> dict:
    """`spec` as a from-rest dataset records each pose: from the rest drape, held `settle`
    seconds (FROM_REST_SETTLE where the spec has no holds)."""
    return {**spec, "from_rest": True, "settle": float(spec.get("settle") or FROM_REST_SETTLE)}


def poses_from_rest(spec: dict, rest: RestDrape, shape, poses: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
    """The cloth [F,n,3] in each pose [F,J,3,3], each simulated on its own from the rest
    drape on `shape` as a `from_rest` dataset of `spec` records it (the blend from the
    A-pose, then held as `from_rest_spec` says), and the message
    of each pose the simulator could not carry, by index (NaN there)."""
    spec = from_rest_spec(spec)
    out = {"x": np.full((len(poses), len(rest.garment.vertices), 3), np.nan, np.float32),
           "penetration_pct": np.full(len(poses), np.nan), "max_speed": np.asarray(0.0),
           "cloth_speed": np.full(len(poses), np.nan, np.float32)}
    failed = {}
    for k in range(len(poses)):
        try:
            simulate_poses(spec, rest, shape, poses[k:k + 1], out, k)
        except SequenceFailed as exc:
            failed[k] = str(exc)
    return out["x"], failed


def simulate_poses(spec: dict, rest: RestDrape, shape, poses: np.ndarray, out: dict, first: int) -> None:
    """Carry the rest drape from the A-pose through `poses`, writing the cloth at each pose
    into `out`'s frames from `first` on and its top speed into `max_speed`. Raises
    SequenceFailed when the simulator cannot carry the cloth (the fail-safe limit counts
    per call: per sequence, or per pose from rest)."""
    from tryon.drape.dress import cloth_on_body
    from tryon.fabric import load_fabric
    from tryon.sim.integrator import ImplicitEulerSolver, StepOptions
    from tryon.sim.obstacles import Motion, Obstacle

    frames, times, pose_keys = body_keyframes(shape, poses, spec)
    d = spec["drape"]
    body = Obstacle("body", frames[0], shape.faces, Motion(keyframes=frames, keyframe_times=times))
    model = cloth_on_body(rest.garment.cloth_mesh(), load_fabric(spec["fabric"]), body, d["thickness"], friction=d["friction"])
    solver = ImplicitEulerSolver(model, StepOptions(max_substep_depth=1))
    try:
        _record_poses(solver, model, spec, shape, times[pose_keys], out, first)
    except TryonError as exc:  # flung, pinched, or the simulator's own failure (e.g. a step that does not converge)
        raise SequenceFailed(f"pose {first}: {exc}" if spec.get("from_rest") else str(exc)) from exc


def _record_poses(solver, model, spec: dict, shape, record_at: np.ndarray, out: dict, first: int) -> None:
    from tryon.drape.fit_metrics import penetration
    from tryon.sim.loop import FailSafeLimit, TopSpeed, run
    from tryon.sim.model import Control

    dt = step_size(spec)
    k = 0

    def record(rec) -> bool:
        nonlocal k
        while k < len(record_at) and rec.state.t >= record_at[k] - 0.5 * dt:
            x = rec.state.x.numpy()
            out["x"][first + k] = x
            out["cloth_speed"][first + k] = top.speeds.max()
            body_now = model.obstacles.vertices_at(rec.state.t)
            out["penetration_pct"][first + k] = penetration(x, body_now, shape.faces)["penetration_pct"]
            k += 1
        return k == len(record_at)

    top = TopSpeed(PLAUSIBLE_SPEED, explain=lambda rec, speed: f"the cloth was flung at {speed:.1f} m/s at t={rec.state.t:.2f} s",
                   error=SequenceFailed)
    failsafe = FailSafeLimit(total=MAX_FAILSAFE_STEPS, error=SequenceFailed, explain=lambda kind, rec, n: (
        f"the collision response needed the rigid fail-safe {n} times by t={rec.state.t:.2f} s (cloth pinched by the pose)"))
    try:
        run(solver, model.initial_state(), dt, int(round(record_at[-1] / dt)) + 1, observers=[top, failsafe, record],
            control=Control(air_damping=spec["drape"]["air_damping"]))
    finally:
        out["max_speed"] = np.asarray(max(float(out["max_speed"]), top.fastest))


@dataclass
class PoseDataset:
    """A pose dataset in memory: one row per sequence; `x` [S,F,n,3]."""

    manifest: Manifest
    arrays: dict[str, np.ndarray]
    rest: RestDrape

    def rows(self, split: str | None = None, ok_only: bool = True) -> np.ndarray:
        return sample_rows(self.arrays, split, ok_only)

    def summary(self) -> dict:
        a = self.arrays
        ok = a["ok"].astype(bool)
        return {"sequences": int(len(ok)), "ok": int(ok.sum()), "poses": int(ok.sum()) * int(a["x"].shape[1]),
                "splits": {str(s): int((a["split"][ok] == s).sum()) for s in np.unique(a["split"])},
                "sources": {str(s): int((a["source"] == s).sum()) for s in np.unique(a["source"])},
                "max_penetration_pct": float(np.nanmax(a["penetration_pct"][ok])) if ok.any() else None,
                "mean_wall_s": float(a["wall_s"].mean())}


def make_pose_dataset(spec: PoseDatasetSpec, out: str | Path, workers: int = 1, ray_address: str | None = None,
                      force: bool = False, progress: bool = True, limit: int | None = None):
    from tryon.dataset.generate import open_dataset, run_generator
    from tryon.dataset.store import software_version

    store = open_dataset(out, spec.manifest(software_version()), force=force)
    report = run_generator(store, lambda m, f: prepare(m, f, progress), pose_unit, workers=workers,
                           ray_address=ray_address, progress=progress, limit=limit)
    return store, report


def load_pose_dataset(folder: str | Path) -> PoseDataset:
    folder = Path(folder)
    manifest = Manifest.read(folder)
    if manifest.kind != KIND:
        raise DatasetError(f"{folder} holds a {manifest.kind!r} dataset, not poses")
    return PoseDataset(manifest, ShardStore(folder, manifest).load(), RestDrape.load(folder))
