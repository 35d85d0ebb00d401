"""Commands that look at photos and video: `tryon person` (the person finder on your own
pictures), `tryon body from-images` (the body from one to four photos) and `tryon motion
from-video` (a person's motion in a video, for `tryon animate --motion`)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from tryon.errors import TryonError
from tryon.sizing.chart import MADE_TO_MEASURE


def _cmd_person(args: argparse.Namespace) -> int:
    from tryon.errors import TryonError
    from tryon.io.atomic import atomic_output_dir, check_output_dir
    from tryon.io.json_safe import dumps_json
    from tryon.perceive.person import KEYPOINTS, PersonNotFound, find_person_in_file, overlay
    from tryon.render.offscreen import save_png

    check_output_dir(args.out, force=args.force)
    found, refused = [], []
    for path in args.images:
        try:
            found.append((Path(path), find_person_in_file(path)))
        except PersonNotFound as exc:
            refused.append(str(exc))
            print(f"refused: {exc}")
    with atomic_output_dir(args.out, force=args.force) as tmp:
        people = []
        for i, (path, p) in enumerate(found):
            picture = f"{i:02d}-{path.stem}-person.png"
            save_png(tmp / picture, overlay(p))
            x0, y0, x1, y1 = p.box
            people.append({"image": str(path), "picture": picture, "people_found": p.people_found, "notes": p.notes,
                           "height_px": p.height_px, "box_px": [v / p.scale for v in (x0, y0, x1, y1)],
                           "keypoints_px": {n: [float(k[0] / p.scale), float(k[1] / p.scale), float(v)]
                                            for n, k, v in zip(KEYPOINTS, p.keypoints, p.visibility)}})
            for note in p.notes:
                print(f"note: {note}")
            print(f"{path}: a person {p.height_px:.0f} px tall -> {args.out}/{picture}")
        with (tmp / "people.json").open("w") as fh:
            fh.write(dumps_json({"people": people, "refused": refused}, indent=2))
    if refused and not found:
        raise TryonError(f"no photo shows a whole standing person ({len(refused)} refused; see above)")
    return 1 if refused else 0


def _cmd_body_from_images(args: argparse.Namespace) -> int:
    from tryon.io.atomic import atomic_output_dir, check_output_dir
    from tryon.learn.body_from_photos import body_from_image_files, write_photo_body

    check_output_dir(args.out, force=args.force)
    pb = body_from_image_files(args.images, args.height_cm, args.gender, args.weight_kg, args.age, args.model)
    with atomic_output_dir(args.out, force=args.force) as tmp:
        report = write_photo_body(pb, tmp)
    for note in pb.notes:
        print(f"note: {note}")
    m = report["measurements"]
    weight = f"{m['weight_kg']:.1f} kg" + ("" if m["weight_given"] else f" (read off the photos, +- {m['weight_kg_sd']:.1f})")
    print(f"{len(args.images)} photo(s) -> {args.height_cm:g} cm, {weight}: chest {m['chest_cm']:.1f} +- "
          f"{m['chest_cm_sd']:.1f}, waist {m['waist_cm']:.1f} +- {m['waist_cm_sd']:.1f}, hip {m['hip_cm']:.1f} +- "
          f"{m['hip_cm_sd']:.1f} cm ({pb.timings['total_s']:.2f} s) -> {args.out}")
    return 0


def _cmd_motion_from_video(args: argparse.Namespace) -> int:
    from tryon.body.fit import Measurements, fit_body
    from tryon.io.atomic import atomic_output_dir, check_output_dir
    from tryon.io.json_safe import dumps_json
    from tryon.io.mesh_io import write_obj
    from tryon.perceive.motion_from_video import facing_forward, motion_picture, read_video_motion
    from tryon.render.offscreen import save_png

    check_output_dir(args.out, force=args.force)
    # the motion is bone rotations, which hardly depend on girth: without a weight, a BMI of 22
    size = {"weight_kg": args.weight_kg} if args.weight_kg is not None else {"bmi": 22.0}
    body = fit_body(Measurements(height_cm=args.height_cm, gender=args.gender, **size))
    vm = read_video_motion(args.source, body.shape, fps=args.fps, start_s=args.start_s, end_s=args.end_s,
                           folder_fps=args.frames_fps)
    report = vm.report()
    with atomic_output_dir(args.out, force=args.force) as tmp:
        facing_forward(vm.motion).save(tmp / "motion.npz")
        write_obj(tmp / "body.obj", vm.shape.vertices.detach().numpy(), np.asarray(vm.shape.faces))
        save_png(tmp / "motion.png", motion_picture(vm))
        with (tmp / "report.json").open("w") as fh:
            fh.write(dumps_json({**report, "height_cm": args.height_cm, "weight_kg": args.weight_kg,
                                 "gender": args.gender}, indent=2))
    print(f"{args.source}: followed in {report['followed_frames']} of {report['frames']} frames "
          f"({report['misread_frames']} misread, left to their neighbours); segments {report['mean_angle_deg']:.1f} "
          f"deg from the landmarks; {np.linalg.norm(report['travel_m']):.2f} m travelled at "
          f"{report['speed_m_s']:.2f} m/s ({report['seconds']:.1f} s) -> {args.out}/motion.npz "
          f"(tryon animate DRAPE --motion {args.out}/motion.npz)")
    return 0


def _resimulation_size_and_edge(args: argparse.Namespace) -> tuple[str | None, float]:
    """--size (a standard size, MADE_TO_MEASURE, or None: the chart's) and --edge-length of --resimulate, checked."""
    from tryon.garment.sizes import SIZES

    edge = 0.03 if args.edge_length is None else args.edge_length
    if not 0.004 <= edge <= 0.05:
        raise TryonError(f"--edge-length {edge} m is outside 0.004-0.05 m")
    size = args.size.upper() if args.size else None
    if size in ("MTM", "MADE-TO-MEASURE"):
        size = MADE_TO_MEASURE
    if size is not None and size not in (*SIZES, MADE_TO_MEASURE):
        raise TryonError(f"--size {args.size}: give one of {', '.join(SIZES)} or made-to-measure")
    return size, edge


def _cmd_perceive(args: argparse.Namespace) -> int:
    from tryon.body.fit import Measurements, fit_body
    from tryon.fabric.presets import load_fabric
    from tryon.garment.drafts import GARMENTS
    from tryon.io.atomic import atomic_output_dir, check_output_dir
    from tryon.learn.fabric_from_video import perceive_video, write_perceived

    if args.garment not in GARMENTS:
        raise TryonError(f"unknown garment {args.garment!r}; use one of {', '.join(GARMENTS)}")
    if (args.fabric or args.size or args.edge_length is not None) and not args.resimulate:
        raise TryonError("--fabric, --size and --edge-length choose what --resimulate simulates; add --resimulate")
    if args.resimulate and not (args.fabric or args.classifier):
        raise TryonError("--resimulate needs a fabric: a --classifier to find it, or --fabric PRESET_OR_JSON")
    fabric = load_fabric(args.fabric) if args.fabric else None  # a bad fabric fails before the work
    size, edge = _resimulation_size_and_edge(args)
    check_output_dir(args.out, force=args.force)
    heft = {"weight_kg": args.weight_kg} if args.weight_kg is not None else {"bmi": 22.0}
    asked = Measurements(height_cm=args.height_cm, gender=args.gender, **heft)
    body = fit_body(asked)
    if size is not None and size != MADE_TO_MEASURE:  # a size too small is refused before the video's work
        from tryon.drape import DrapeRequest
        from tryon.drape.pipeline import check_size_fits

        check_size_fits(DrapeRequest(asked, garment=args.garment, size=size), body)
    seen = perceive_video(args.source, body.shape, args.garment, start_s=args.start_s, classifier=args.classifier,
                          folder_fps=args.frames_fps)
    sim = None
    if args.resimulate:
        from tryon.learn.video_resimulation import resimulate

        sim = resimulate(seen.video, body, asked, args.garment, fabric or seen.fabric, size=size, edge_length=edge)
    with atomic_output_dir(args.out, force=args.force) as tmp:
        report = write_perceived(seen, tmp, sim)
    for note in report["notes"]:
        print(f"note: {note}")
    m = report["motion"]
    print(f"{args.source}: the person followed in {m['followed_frames']} of {m['frames']} frames; of the "
          f"{report['classifier_frames']} frames the classifier reads (5 a second), the {args.garment} is found in "
          f"{report['garment_found_frames']}; motion -> {args.out}/motion.npz")
    if report["fabric"]:
        f = report["fabric"]
        print(f"fabric class {f['class']} ({100 * f['probability']:.0f} %; nearest measured fabrics: "
              f"{', '.join(f['nearest_presets'])}) -> {args.out}/fabric.json (tryon drape --fabric)")
    if sim is not None:
        r = report["resimulation"]
        print(f"re-simulated: {args.garment} {r['size']} in {r['fabric']}, {r['frames']} frames, peak strain "
              f"{100 * r['max_strain']:.0f} % (at the end {100 * r['final_max_strain']:.0f} %), {r['seconds']:.0f} s "
              f"-> {args.out}/resimulated.png")
    return 0


def add_photo_body_args(p: argparse.ArgumentParser, required: bool) -> None:
    """The person's own numbers that go with photos (stature fixes the scale)."""
    p.add_argument("--height-cm", type=float, required=required, help="stature in cm (fixes the photos' scale)")
    p.add_argument("--gender", choices=["female", "male"], required=required)


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("person", help="find the person in photos (mask and keypoints, BlazePose): an overlay per "
                       "photo, or the reason it cannot be used")
    p.add_argument("images", nargs="+", metavar="IMG", help="photos (JPEG, PNG, ...) of one whole standing person")
    p.add_argument("--out", required=True, help="folder for the overlays and people.json")
    p.add_argument("--force", action="store_true", help="replace an --out folder tryon did not write")
    p.set_defaults(func=_cmd_person)
    b = sub.add_parser("body", help="bodies from photos (tryon body from-images)")
    kinds = b.add_subparsers(dest="kind", required=True)
    f = kinds.add_parser("from-images", help="the body from 1-4 photos of one whole standing person, with stature "
                                             "and gender: body.obj, measurements.json, an overlay per photo")
    f.add_argument("images", nargs="+", metavar="IMG", help="photos of the same person from any sides (front, side, "
                                                             "back), head to feet")
    add_photo_body_args(f, required=True)
    f.add_argument("--weight-kg", type=float, help="weight in kg (optional: read off the photos when not given)")
    f.add_argument("--age", type=float, default=30.0)
    f.add_argument("--model", help="a body-from-photos model.npz (default: the shipped one)")
    f.add_argument("--out", required=True, help="folder for body.obj, measurements.json, overlays, report.json")
    f.add_argument("--force", action="store_true", help="replace an --out folder tryon did not write")
    f.set_defaults(func=_cmd_body_from_images)
    m = sub.add_parser("motion", help="motions from video (tryon motion from-video)")
    kinds = m.add_subparsers(dest="kind", required=True)
    v = kinds.add_parser("from-video", help="the motion of the person in a video (or folder of frames), followed "
                                            "frame by frame: motion.npz for tryon animate --motion, a picture, a report")
    v.add_argument("source", help="a video file (mp4, mov, avi, ...) or a folder of frames in name order")
    add_photo_body_args(v, required=True)
    v.add_argument("--weight-kg", type=float, default=None, help="weight in kg (default: a BMI of 22; the motion hardly depends on it)")
    v.add_argument("--fps", type=float, default=15.0, help="frames a second read from the video")
    v.add_argument("--frames-fps", type=float, default=15.0, help="a folder of frames: the rate they were taken at")
    v.add_argument("--start-s", type=float, default=0.0, help="start this many seconds into the video")
    v.add_argument("--end-s", type=float, default=None, help="stop this many seconds into the video")
    v.add_argument("--out", required=True, help="folder for motion.npz, body.obj, motion.png, report.json")
    v.add_argument("--force", action="store_true", help="replace an --out folder tryon did not write")
    v.set_defaults(func=_cmd_motion_from_video)
    c = sub.add_parser("perceive", help="a clip of a person in a garment: their motion, the garment in each frame and, "
                                        "with a trained classifier, the fabric class (docs/FABRIC_FROM_VIDEO.md)")
    c.add_argument("source", help="a video file or a folder of frames; 5 s are read from --start-s")
    add_photo_body_args(c, required=True)
    c.add_argument("--weight-kg", type=float, default=None, help="weight in kg (default: a BMI of 22)")
    c.add_argument("--garment", required=True, help="the garment worn: tshirt, longsleeve, trousers, skirt, dress")
    c.add_argument("--start-s", type=float, default=0.0, help="start this many seconds into the video")
    c.add_argument("--frames-fps", type=float, default=15.0, help="a folder of frames: the rate they were taken at")
    c.add_argument("--classifier", help="a fabric classifier from tryon train fabric-video (image-only methods)")
    c.add_argument("--resimulate", action="store_true",
                   help="drape the garment on the body and move it through the video's motion in the fabric found "
                        "(or --fabric): resimulated.npz and resimulated.png, the video above the simulation")
    c.add_argument("--fabric", help="--resimulate: the fabric to simulate (preset or .json; default: the class's)")
    c.add_argument("--size", help="--resimulate: the garment's size (default: the body's size by the chart)")
    c.add_argument("--edge-length", type=float, default=None,
                   help="--resimulate: the garment's triangle edge length in metres (default 0.03, as the clips)")
    c.add_argument("--out", required=True, help="folder for motion.npz, body.obj, frames.png, report.json, fabric.json")
    c.add_argument("--force", action="store_true", help="replace an --out folder tryon did not write")
    c.set_defaults(func=_cmd_perceive)
