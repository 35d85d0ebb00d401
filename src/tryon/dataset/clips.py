"""Clip datasets for fabric from video: a garment of a known fabric class on a sampled
body moving through a motion, kept as the simulation (garment points per frame and what
makes the body's frames again), to be rendered into pictures by a later stage.

A unit draws a body (`bodies.sample_body`, as the drape datasets do), its own size of the
garment (the size whose chart girths lie nearest), a fabric class (unit % 54: every class
equally often) and a fabric inside it (`FabricClasses.sample_fabric`: a measured fabric
scaled into the class), a built-in motion with a speed and an amplitude, and a time of
day for the clip to start in the motion. The garment of that size is dressed once on its
fit model (`drapes.build_references`, shared by every clip of the size), draped onto the
body as `tryon drape` does (in the clip's fabric), then the body blends from the A-pose
into the motion and the garment follows (`tryon.drape.animate.garment_motion_scene`).
The clip is `frames` frames at `fps` after the blend (the chapter's clips: 25 at 5 fps).
A dataset that names measured fabrics (`presets`) takes them in turn exactly as measured
instead: the held-out clips `tryon bench perceive` judges on.

Stored per clip: the garment's vertices per frame (float32, metres) and at rest before
the motion, the frame times, the fabric class with the fabric's features and data, the
body (shape vector, gender, stature, BMI), the motion (name, speed, amplitude), the size,
the split, how the simulation went, and the clip filmed (`film_clip`): per frame what the
person finder sees (mask and keypoints in the crop around the person) and the garment's
true mask, with the camera.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import numpy as np

from tryon.body.motion import BLEND_TIME, BUILTIN_MOTIONS, load_motion, motion_start
from tryon.body.motion_data import BodyMotion
from tryon.body.measure import drafting_measurements
from tryon.body.pose import BodyPose, posed_body
from tryon.dataset.bodies import BodyRanges, sample_body
from tryon.dataset.drapes import (
    DATASET_DRAPE, GENDER_CODE, Reference, build_references, own_size_index, shape_vector, split_of,
)
from tryon.dataset.store import DatasetError, Manifest
from tryon.drape.animate import GarmentAtRest, garment_motion_scene
from tryon.drape.pipeline import DrapeRequest, drape_pose, simulate_drape
from tryon.errors import TryonError
from tryon.fabric.blend import fabric_features
from tryon.fabric.wang2011 import MEASURED_FABRICS, WangFabric
from tryon.garment.drafts import GARMENTS
from tryon.garment.sizes import SIZES
from tryon.perceive.fabric_classes import FabricClasses, default_classes

KIND = "clips"
GENERATOR_VERSION = 1
SPEED = (0.7, 1.4)       # the motion played this many times its recorded speed
AMPLITUDE = (0.6, 1.2)   # its joint rotations (from the rest pose) scaled by this


@dataclass
class ClipDatasetSpec:
    """`count` clips of one garment."""

    garment: str = "tshirt"
    sizes: tuple[str, ...] = ("XS", "S", "M", "L", "XL", "XXL")
    count: int = 540
    edge_length: float = 0.03
    frames: int = 25
    fps: float = 5.0
    dt: float = 0.01
    motions: tuple[str, ...] = BUILTIN_MOTIONS
    seed: int = 0
    ranges: BodyRanges = field(default_factory=lambda: BodyRanges(bmi=(17.0, 38.0)))
    reference_fabric: str = "gray-interlock"  # what the sizes are dressed in on their fit models
    topology: tuple[str, str] = ("female", "M")
    shard_size: int = 32
    presets: tuple[str, ...] = ()  # measured fabrics taken in turn as measured, instead of fabrics drawn in classes
    train_fraction: float = 0.8
    val_fraction: float = 0.1

    def validate(self) -> None:
        if self.garment not in GARMENTS:
            raise TryonError(f"unknown garment {self.garment!r}; clips dress one of {', '.join(GARMENTS)}")
        self.sizes = tuple(s.upper() for s in self.sizes)
        bad = [s for s in self.sizes if s not in SIZES]
        if bad or not self.sizes or list(self.sizes) != [s for s in SIZES if s in self.sizes]:
            raise TryonError(f"sizes {list(self.sizes)}: give distinct standard sizes in order ({', '.join(SIZES)})")
        if not 1 <= self.count <= 1_000_000:
            raise TryonError(f"--count {self.count}: give 1 to 1,000,000 clips")
        if not 0.008 <= self.edge_length <= 0.05:
            raise TryonError(f"edge length {self.edge_length} m is outside 0.008-0.05 m")
        if not (2 <= self.frames <= 300 and 1.0 <= self.fps <= 30.0):
            raise TryonError(f"{self.frames} frames at {self.fps} fps: give 2-300 frames at 1-30 fps")
        if not 0.001 <= self.dt <= 1.0 / 30.0 or self.dt > 1.0 / self.fps:
            raise TryonError(f"time step {self.dt} s: give 0.001-0.033 s, no longer than a frame")
        bad = [m for m in self.motions if m not in BUILTIN_MOTIONS]
        if bad or not self.motions:
            raise TryonError(f"motions {list(self.motions)}: use some of {', '.join(BUILTIN_MOTIONS)}")
        if not 1 <= self.shard_size <= 4096:
            raise TryonError(f"shard size {self.shard_size} is outside 1-4096 samples")
        bad = [p for p in self.presets if p not in MEASURED_FABRICS]
        if bad:
            raise TryonError(f"unknown measured fabric {', '.join(bad)}: clips on measured fabrics take some of "
                             f"{', '.join(MEASURED_FABRICS)}")

    def manifest(self, software_version: str, classes: FabricClasses | None = None) -> Manifest:
        self.validate()
        classes = classes or default_classes()
        spec = {"garment": self.garment, "sizes": list(self.sizes), "edge_length": self.edge_length,
                "frames": self.frames, "fps": self.fps, "dt": self.dt, "motions": list(self.motions),
                "blend_time": BLEND_TIME, "speed": list(SPEED), "amplitude": list(AMPLITUDE),
                "ranges": self.ranges.to_dict(), "fabric": self.reference_fabric,
                "topology": {"gender": self.topology[0], "size": self.topology[1]},
                "fabric_classes": {k: v for k, v in classes.to_dict().items() if k != "provenance"},
                "drape": {"max_settle_time": 1.0}}
        if self.presets:  # only then: the manifests of class-drawn datasets stay as they were
            spec["presets"] = list(self.presets)
        split = {"rule": "by body: train / val / test drawn per body from the seed", "train": self.train_fraction,
                 "val": self.val_fraction, "extrapolation_bmi": None}
        return Manifest(KIND, GENERATOR_VERSION, software_version, self.seed, self.count, self.shard_size, spec, split,
                        created=time.strftime("%Y-%m-%dT%H:%M:%S%z"))


def varied_motion(motion: BodyMotion, speed: float, amplitude: float) -> BodyMotion:
    """`motion` played `speed` times as fast, its rotations and root travel scaled by `amplitude`."""
    return BodyMotion(motion.rotations * amplitude, list(motion.bone_labels), motion.fps * speed,
                      motion.root_translation * amplitude, f"{motion.name}x{speed:.2f}a{amplitude:.2f}")


def clip_motion(manifest: Manifest, unit: int) -> tuple[BodyMotion, dict[str, np.ndarray]]:
    """The unit's motion, long enough for the clip, and what a sample records of it."""
    spec = manifest.spec
    rng = np.random.default_rng([manifest.seed, unit, 21])
    name = spec["motions"][int(rng.integers(len(spec["motions"])))]
    speed, amplitude = float(rng.uniform(*spec["speed"])), float(rng.uniform(*spec["amplitude"]))
    motion = varied_motion(load_motion(name), speed, amplitude)
    needed = (spec["frames"] - 1) / spec["fps"]
    cycles = int(np.ceil(needed / max(motion.duration, 1e-9))) + 1
    record = {"motion": np.asarray(spec["motions"].index(name)), "motion_speed": np.asarray(speed),
              "motion_amplitude": np.asarray(amplitude)}
    return motion.repeated(cycles), record


def clip_fabric(manifest: Manifest, unit: int):
    """The unit's fabric class and fabric: a measured fabric in turn when the dataset names
    some (`presets`), else a fabric drawn inside class unit % 54."""
    classes = FabricClasses.from_dict(manifest.spec["fabric_classes"])
    presets = manifest.spec.get("presets")
    if presets:
        fabric = WangFabric.from_preset(presets[unit % len(presets)])
        return classes.class_of(fabric), fabric
    c = unit % classes.count
    fabric = classes.sample_fabric(c, np.random.default_rng([manifest.seed, unit, 17]))
    return c, fabric


def prepare_clips(manifest: Manifest, folder) -> dict[tuple[str, str], Reference]:
    """The references of every size that dresses; a size whose garment cannot be dressed at
    the dataset's edge length is left out (its clips are recorded as failed, naming why)."""
    refs: dict[tuple[str, str], Reference] = {}
    for size in manifest.spec["sizes"]:
        one = copy.deepcopy(manifest)
        one.spec["sizes"] = [size]
        try:
            refs.update(build_references(one, folder, progress=True))
        except TryonError as exc:
            print(f"size {size} left out of the clips: {exc}", flush=True)
            refs.update({(g, size): str(exc) for g in BodyRanges.from_dict(manifest.spec["ranges"]).genders})
    if all(isinstance(r, str) for r in refs.values()):
        raise DatasetError(f"no size of the {manifest.spec['garment']} could be dressed at "
                           f"{manifest.spec['edge_length']} m edges; try a shorter --edge-length")
    return refs


def clip_unit(manifest: Manifest, refs: dict[tuple[str, str], Reference], unit: int) -> dict[str, np.ndarray]:
    """One clip as a flat dict of arrays (see the module docstring)."""
    from tryon.sim.runner import simulate

    t0 = time.perf_counter()
    spec = manifest.spec
    body = sample_body(manifest.seed, unit, BodyRanges.from_dict(spec["ranges"]))
    shape = body.shape()
    m = drafting_measurements(shape)
    first = SIZES.index(spec["sizes"][0])
    size = spec["sizes"][int(np.clip(own_size_index(spec["garment"], body.gender, m) - first, 0, len(spec["sizes"]) - 1))]
    ref = refs[(body.gender, size)]
    c, fabric = clip_fabric(manifest, unit)
    motion, motion_record = clip_motion(manifest, unit)
    start_pose = drape_pose(shape, spec["garment"])
    target = posed_body(shape, start_pose, m["crotch_height"])
    # every sample holds the same arrays (a shard stacks them): a failed one holds NaN / zeros
    n = next(len(r.garment.vertices) for r in refs.values() if not isinstance(r, str))
    frames = spec["frames"]
    data = fabric.to_arcsim_dict()
    out = {"body": np.asarray(body.index), "size": np.asarray(spec["sizes"].index(size)),
           "gender": np.asarray(GENDER_CODE[body.gender]), "height_cm": np.asarray(body.height_cm),
           "bmi": np.asarray(body.bmi), "shape_params": shape_vector(body.params),
           "split": np.asarray(split_of(manifest, body.index, body.bmi)), "fabric_class": np.asarray(c),
           "fabric_features": fabric_features(fabric), "fabric_density": np.asarray(float(fabric.density)),
           "fabric_stretching": np.asarray(data["stretching"]), "fabric_bending": np.asarray(data["bending"]),
           **motion_record,
           "x": np.full((frames, n, 3), np.nan, np.float32), "x_rest": np.full((n, 3), np.nan, np.float32),
           "times": np.zeros(frames), "ok": np.asarray(False), "error": np.asarray(""), "drape_steps": np.asarray(0),
           "motion_steps": np.asarray(0), "max_strain": np.asarray(np.nan), **unfilmed(frames)}
    if isinstance(ref, str):  # the size could not be dressed (prepare_clips)
        out.update({"error": np.asarray(f"the {size} garment could not be dressed: {ref}"[:500]),
                    "wall_s": np.asarray(time.perf_counter() - t0)})
        return out
    req = DrapeRequest(body.measurements(), garment=spec["garment"], size=size, fabric=data,
                       edge_length=spec["edge_length"], **spec["drape"], **DATASET_DRAPE)
    try:
        x_rest, _, _, stats, _ = simulate_drape(req, ref.garment, ref.pose(), target, progress=False)
        out.update({"x_rest": x_rest.astype(np.float32), "drape_steps": np.asarray(int(stats["steps"]))})
        g = ref.garment
        duration = BLEND_TIME + (frames - 1) / spec["fps"]
        scene = garment_motion_scene(shape, start_pose, GarmentAtRest(x_rest, g.uv, g.faces, g.corner_uv, spec["garment"]),
                                     fabric, motion, req.thickness, req.friction, spec["dt"], duration)
        scene.frame_time = frame_step(spec["dt"], spec["fps"]) * spec["dt"]
        result = simulate(scene, progress=False)
    except TryonError as exc:  # recorded as failed; the dataset goes on
        out.update({"error": np.asarray(str(exc)[:500]), "wall_s": np.asarray(time.perf_counter() - t0)})
        return out
    x, t = clip_frames(np.asarray(result.positions), np.asarray(result.times), frames, spec["fps"])
    bodies = np.stack([scene.model.obstacles.vertices_at(float(ti)) for ti in t])
    rng = np.random.default_rng([manifest.seed, unit, 23])
    out.update(film_clip(posed_body(shape, start_pose), bodies, x, g.faces, spec["garment"], rng))
    out.update({"x": x.astype(np.float32), "times": t, "ok": np.asarray(bool(np.isfinite(x).all())),
                "motion_steps": np.asarray(int(result.summary["steps"])),
                "max_strain": np.asarray(float(result.summary["max_strain"])),
                "wall_s": np.asarray(time.perf_counter() - t0)})
    return out


def film_clip(start: BodyPose, bodies: np.ndarray, garment_x: np.ndarray, garment_faces: np.ndarray, garment: str,
              rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The clip filmed by one still camera (drawn as the photo datasets draw theirs, from
    within 90 degrees of the front), the body in painted clothes and a skin tone, the
    garment in one colour, on a wall-and-floor background; per frame what the person finder
    (BlazePose, `tryon.perceive.person`) sees in the picture, cropped as the photo datasets
    crop it, the garment's mask found in the picture (`tryon.perceive.garment_mask`, as on
    real frames) and its true mask, both in the same crop."""
    from tryon.dataset.photos import IMAGE_WH, TRUE_CROP, _background, _camera, _clothes_colours
    from tryon.perceive.frame_features import frame_features
    from tryon.perceive.person import crop_mask, detect_person
    from tryon.render.offscreen import RenderMesh, render_meshes

    w, h = IMAGE_WH
    body_colours = _clothes_colours(start, rng)
    cloth = np.clip(rng.uniform(0.05, 0.95, 3), 0.0, 1.0)
    azimuth = float(rng.uniform(-90.0, 90.0))
    cam = _camera(np.concatenate([bodies.reshape(-1, 3), garment_x.reshape(-1, 3)]), azimuth, rng)
    wall = _background(rng, IMAGE_WH)
    per_frame: dict[str, list] = {k: [] for k in ("found", "crop", "mask_bits", "garment_mask_bits",
                                                  "found_garment_bits", "keypoints", "visibility")}
    for body_v, gx in zip(bodies, garment_x):
        meshes = [RenderMesh(body_v, start.faces, vertex_colors=body_colours),
                  RenderMesh(gx, garment_faces, color=tuple(cloth), two_sided=True)]
        fg = render_meshes(meshes, w, h, cam, background=(1.0, 0.0, 1.0))
        key = (fg[..., 0] > 250) & (fg[..., 1] < 5) & (fg[..., 2] > 250)
        photo = np.where(key[..., None], wall, fg)
        # the garment's pixels: where it is in front (drawn again in pure green, the body in blue)
        ids = render_meshes([RenderMesh(body_v, start.faces, color=(0.0, 0.0, 1.0)),
                             RenderMesh(gx, garment_faces, color=(0.0, 1.0, 0.0), two_sided=True)], w, h, cam,
                            background=(0.0, 0.0, 0.0))
        garment_mask = (ids[..., 1].astype(int) > ids[..., 2].astype(int) + 10).astype(np.float32)
        p = detect_person(photo, "clip frame")
        ys, xs = np.nonzero(~key)
        seen, crop = frame_features(photo, p, garment, box=(int(xs.min()), int(ys.min()), int(xs.max()) + 1,
                                                            int(ys.max()) + 1))
        for k, v in seen.items():
            per_frame[k].append(v)
        per_frame["garment_mask_bits"].append(np.packbits(crop_mask(garment_mask, crop, TRUE_CROP) > 0.5))
    out = {f"frame_{k}": np.stack(v) for k, v in per_frame.items()}
    out.update({"camera_azimuth_deg": np.float32(azimuth), "camera_fov_deg": np.float32(cam.fov_deg),
                "camera_eye": cam.eye.astype(np.float32), "camera_target": cam.target.astype(np.float32),
                "garment_colour": cloth.astype(np.float32)})
    return out


def unfilmed(frames: int) -> dict[str, np.ndarray]:
    """What `film_clip` stores, for a clip that was not filmed (zeros; nothing found)."""
    from tryon.dataset.photos import CROP, TRUE_CROP

    return {"frame_found": np.zeros(frames, bool), "frame_crop": np.zeros((frames, 3), np.float32),
            "frame_mask_bits": np.zeros((frames, CROP * CROP // 8), np.uint8),
            "frame_garment_mask_bits": np.zeros((frames, TRUE_CROP * TRUE_CROP // 8), np.uint8),
            "frame_found_garment_bits": np.zeros((frames, TRUE_CROP * TRUE_CROP // 8), np.uint8),
            "frame_keypoints": np.zeros((frames, 33, 2), np.float16), "frame_visibility": np.zeros((frames, 33), np.float16),
            "camera_azimuth_deg": np.float32(0), "camera_fov_deg": np.float32(0), "camera_eye": np.zeros(3, np.float32),
            "camera_target": np.zeros(3, np.float32), "garment_colour": np.zeros(3, np.float32)}


def frame_step(dt: float, fps: float) -> int:
    """Steps between recorded frames such that every clip frame (BLEND_TIME + k / fps) is
    recorded exactly and few others are (each recorded frame is measured: intersections,
    distances), e.g. 10 at dt 0.01 and 5 fps; 1 when the times do not fall on steps."""
    import math

    blend, per = BLEND_TIME / dt, 1.0 / (fps * dt)
    if abs(blend - round(blend)) > 1e-6 or abs(per - round(per)) > 1e-6:
        return 1
    return max(1, math.gcd(round(blend), round(per)))


def clip_frames(positions: np.ndarray, times: np.ndarray, frames: int, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """The `frames` recorded frames nearest BLEND_TIME + k / fps (the clip after the blend)."""
    want = BLEND_TIME + np.arange(frames) / fps
    idx = np.abs(times[None, :] - want[:, None]).argmin(axis=1)
    if np.abs(times[idx] - want).max() > 0.5 / fps:
        raise TryonError(f"the simulation recorded no frame near {want[np.abs(times[idx] - want).argmax()]:.2f} s")
    return positions[idx], times[idx]


def clip_for_refinement(manifest: Manifest, folder, sample: dict, frames: int | None = None):
    """A finished clip as the fabric refinement sees it (`tryon.perceive.refine_fabric`):
    its first `frames` frames (all by default), the body moving as it moved, the garment's
    rest shape; and the clip's true fabric."""
    from tryon.dataset.loading import reference_garments
    from tryon.perceive.refine_fabric import ClipToRefine, motion_after

    spec = manifest.spec
    unit = int(sample["unit"])
    if not bool(sample["ok"]):
        raise TryonError(f"clip {unit} did not finish ({sample['error']}); nothing to refine on")
    body = sample_body(manifest.seed, unit, BodyRanges.from_dict(spec["ranges"]))
    shape = body.shape()
    motion, _ = clip_motion(manifest, unit)
    # the motion's own clock at the clip's first frame (the blend lasts whole motion frames)
    t0 = BLEND_TIME - motion_start(motion)
    frames = frames or len(sample["x"])
    moved, start, offset = motion_after(motion, shape, t0, (frames - 1) / spec["fps"])
    gender = next(g for g, code in GENDER_CODE.items() if code == int(sample["gender"]))
    ref = reference_garments(folder)[(gender, spec["sizes"][int(sample["size"])])]
    req = DrapeRequest(body.measurements(), garment=spec["garment"], size=spec["sizes"][int(sample["size"])],
                       fabric=spec["fabric"], edge_length=spec["edge_length"], **DATASET_DRAPE)
    clip = ClipToRefine(shape, start, moved, np.asarray(sample["x"][:frames], np.float64) - offset, 1.0 / spec["fps"],
                        ref.uv, ref.faces, ref.corner_uv, spec["garment"], req.thickness, req.friction, spec["dt"])
    return clip, clip_fabric(manifest, unit)[1]


def make_clip_dataset(spec: ClipDatasetSpec, out, workers: int = 1, ray_address: str | None = None,
                      force: bool = False, progress: bool = True, limit: int | None = None):
    from tryon.dataset.generate import open_dataset, run_generator
    from tryon.dataset.store import software_version

    store = open_dataset(out, spec.manifest(software_version()), force=force)
    report = run_generator(store, prepare_clips, clip_unit, workers=workers, ray_address=ray_address,
                           progress=progress, limit=limit)
    return store, report


