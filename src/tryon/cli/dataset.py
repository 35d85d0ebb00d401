"""`tryon dataset`: datasets for the learned systems (tryon.dataset)."""

from __future__ import annotations

import argparse
import json


def _print_run(store, report) -> None:
    """What a generator run made, and the dataset it left, as JSON."""
    from tryon.dataset import load_drape_dataset

    print(json.dumps({"made": report.made, "skipped": report.skipped, "failed": report.failed,
                      "wall_s": round(report.wall_s, 1), "samples_per_core_hour": round(report.samples_per_core_hour, 1),
                      **load_drape_dataset(store.folder).summary()}, indent=1))


def _generator_args(p: argparse.ArgumentParser) -> None:
    """The options every resumable dataset generator takes."""
    p.add_argument("--limit", type=int, help="make at most this many missing samples in this run (the rest on resume)")
    p.add_argument("--out", required=True, help="dataset folder; an existing dataset with the same settings is resumed")
    p.add_argument("--workers", type=int, default=1, help="Ray workers (1: in this process)")
    p.add_argument("--ray-address", help="join a Ray cluster (host:port) instead of starting a local one")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--force", action="store_true", help="use an existing --out folder tryon did not write")


def _cmd_dataset_drape(args: argparse.Namespace) -> int:
    from tryon.dataset import BodyRanges, DrapeDatasetSpec, make_drape_dataset
    from tryon.io.atomic import check_output_dir

    # skirts and dresses are drafted for women; the other garments for everyone
    genders = args.genders or (["female"] if args.garment in ("skirt", "dress") else ["female", "male"])
    spec = DrapeDatasetSpec(garment=args.garment, sizes=tuple(args.sizes), count=args.count, fabric=args.fabric,
                            edge_length=args.edge_length, seed=args.seed, shard_size=args.shard_size,
                            ranges=BodyRanges(genders=tuple(genders), bmi=tuple(args.bmi)),
                            extrapolation_bmi=args.extrapolation_bmi,
                            fabrics=tuple(args.fabrics) if args.fabrics else None, fabric_mix=args.fabric_mix,
                            size_window=args.size_window)
    spec.validate()  # every argument is checked before the first body or drape
    check_output_dir(args.out, force=args.force)
    store, report = make_drape_dataset(spec, args.out, workers=args.workers, ray_address=args.ray_address,
                                       force=args.force, progress=not args.quiet, limit=args.limit)
    _print_run(store, report)
    print(f"dataset: {store.folder} (manifest.json, shards/, references/)")
    return 0


def _cmd_dataset_poses(args: argparse.Namespace) -> int:
    from tryon.dataset.poses import PoseDatasetSpec, load_pose_dataset, make_pose_dataset
    from tryon.io.atomic import check_output_dir

    spec = PoseDatasetSpec(garment=args.garment, size=args.size, gender=args.gender, fabric=args.fabric,
                           edge_length=args.edge_length, count=args.count, frames=args.frames, seed=args.seed,
                           shard_size=args.shard_size, settle=args.settle, from_rest=args.from_rest)
    spec.validate()
    check_output_dir(args.out, force=args.force)
    store, report = make_pose_dataset(spec, args.out, workers=args.workers, ray_address=args.ray_address,
                                      force=args.force, progress=not args.quiet, limit=args.limit)
    print(json.dumps({"made": report.made, "skipped": report.skipped, "failed": report.failed,
                      "wall_s": round(report.wall_s, 1), "sequences_per_core_hour": round(report.samples_per_core_hour, 1),
                      **load_pose_dataset(store.folder).summary()}, indent=1))
    print(f"dataset: {store.folder} (manifest.json, rest.npz, shards/)")
    return 0


def _cmd_dataset_bodies(args: argparse.Namespace) -> int:
    from tryon.dataset import BodyRanges
    from tryon.dataset.photos import PhotoDatasetSpec, make_photo_dataset
    from tryon.io.atomic import check_output_dir

    spec = PhotoDatasetSpec(count=args.count, seed=args.seed, shard_size=args.shard_size,
                            ranges=BodyRanges(genders=tuple(args.genders), bmi=tuple(args.bmi)))
    spec.validate()
    check_output_dir(args.out, force=args.force)
    store, report = make_photo_dataset(spec, args.out, workers=args.workers, ray_address=args.ray_address,
                                       force=args.force, progress=not args.quiet, limit=args.limit)
    print(json.dumps({"made": report.made, "skipped": report.skipped, "failed": report.failed,
                      "wall_s": round(report.wall_s, 1), "people_per_core_hour": round(report.samples_per_core_hour, 1)},
                     indent=1))
    print(f"dataset: {store.folder} (manifest.json, shards/)")
    return 0


def _cmd_dataset_clips(args: argparse.Namespace) -> int:
    from tryon.dataset import BodyRanges
    from tryon.dataset.clips import ClipDatasetSpec, make_clip_dataset
    from tryon.io.atomic import check_output_dir

    genders = args.genders or (["female"] if args.garment in ("skirt", "dress") else ["female", "male"])
    spec = ClipDatasetSpec(garment=args.garment, sizes=tuple(args.sizes), count=args.count, edge_length=args.edge_length,
                           frames=args.frames, fps=args.fps, motions=tuple(args.motions), seed=args.seed,
                           ranges=BodyRanges(genders=tuple(genders), bmi=tuple(args.bmi)), shard_size=args.shard_size,
                           presets=tuple(args.presets or ()))
    spec.validate()
    check_output_dir(args.out, force=args.force)
    store, report = make_clip_dataset(spec, args.out, workers=args.workers, ray_address=args.ray_address,
                                      force=args.force, progress=not args.quiet, limit=args.limit)
    print(json.dumps({"made": report.made, "skipped": report.skipped, "failed": report.failed,
                      "wall_s": round(report.wall_s, 1), "clips_per_core_hour": round(report.samples_per_core_hour, 1)},
                     indent=1))
    print(f"dataset: {store.folder} (manifest.json, shards/, references/)")
    return 0


def _cmd_dataset_pack(args: argparse.Namespace) -> int:
    from tryon.dataset.loading import load_drape_dataset
    from tryon.dataset.pack import pack_dataset
    from tryon.dataset.poses import KIND as POSES, load_pose_dataset
    from tryon.dataset.store import Manifest

    out = pack_dataset(args.dataset, args.out, force=args.force, splits=args.splits)
    load = load_pose_dataset if Manifest.read(out).kind == POSES else load_drape_dataset
    print(json.dumps(load(out).summary(), indent=1))
    print(f"compact dataset: {out}")
    return 0


def _cmd_dataset_refine(args: argparse.Namespace) -> int:
    from tryon.io.atomic import check_output_dir
    from tryon.learn.model import shipped_model_path
    from tryon.learn.selfcorrect import make_refined_dataset

    check_output_dir(args.out, force=args.force)
    model = args.model or shipped_model_path("tshirt")
    store, report = make_refined_dataset(args.source, model, args.count, args.out, seed=args.seed, workers=args.workers,
                                         ray_address=args.ray_address, force=args.force, progress=not args.quiet,
                                         limit=args.limit)
    _print_run(store, report)
    print(f"refined dataset: {store.folder}; train on it with tryon train drape --data {args.source} {store.folder}")
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register `tryon dataset ...` on the `tryon` parser."""
    d = sub.add_parser("dataset", help="make datasets for the learned systems (resumable, Ray)")
    kinds = d.add_subparsers(dest="kind", required=True)
    p = kinds.add_parser("drape", help="a garment in several sizes draped on sampled bodies (what `tryon drape` gives)")
    p.add_argument("--garment", default="tshirt", help="tshirt, longsleeve, skirt, trousers or dress")
    p.add_argument("--sizes", nargs="+", default=["S", "M", "L"], help="standard sizes; every body is draped in each")
    p.add_argument("--count", type=int, default=100, help="bodies (samples per size)")
    p.add_argument("--fabric", default="gray-interlock", help="fabric preset (with --fabrics: the references' fabric)")
    p.add_argument("--fabrics", nargs="+", help="draw each drape's fabric from these measured presets")
    p.add_argument("--fabric-mix", type=float, default=0.0,
                   help="with --fabrics: the share of drapes whose fabric is blended between two of them")
    p.add_argument("--size-window", type=int,
                   help="drape each body in this many of --sizes around its own (one smaller, its own, larger) "
                        "instead of in every size")
    p.add_argument("--edge-length", type=float, default=0.012, help="garment triangle edge length in metres")
    p.add_argument("--genders", nargs="+", choices=["female", "male"],
                   help="default: female for skirt and dress, both for the other garments")
    p.add_argument("--bmi", type=float, nargs=2, default=[17.0, 45.0], metavar=("LOW", "HIGH"), help="BMI range (uniform)")
    p.add_argument("--extrapolation-bmi", type=float, default=40.0,
                   help="bodies at or above this BMI form the extrapolation split (held out of training)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--shard-size", type=int, default=32, help="samples per shard file")
    _generator_args(p)
    p.set_defaults(func=_cmd_dataset_drape)
    r = kinds.add_parser("refine", help="self-correction: a model's predictions on more bodies, refined by physics, "
                                        "as a drape dataset to train on with the simulated one")
    r.add_argument("--from", dest="source", required=True, help="the simulated drape dataset the model was trained on")
    r.add_argument("--model", help="model file (default: the shipped T-shirt model)")
    r.add_argument("--count", type=int, default=100, help="bodies (samples per size)")
    r.add_argument("--seed", type=int, help="body seed (default: the source's + 1000, so no body repeats)")
    _generator_args(r)
    r.set_defaults(func=_cmd_dataset_refine)
    q = kinds.add_parser("poses", help="one garment on one body through many pose sequences (for tryon train kdsm)")
    q.add_argument("--garment", default="tshirt", help="tshirt, longsleeve or dress")
    q.add_argument("--size", default="M", help="the size; the body is its fit model")
    q.add_argument("--gender", default="female", choices=["female", "male"])
    q.add_argument("--fabric", default="gray-interlock", help="fabric preset")
    q.add_argument("--edge-length", type=float, default=0.015, help="garment triangle edge length in metres")
    q.add_argument("--count", type=int, default=300, help="sequences")
    q.add_argument("--frames", type=int, default=32, help="poses per sequence (30 per second of motion)")
    q.add_argument("--settle", type=float, default=0.0,
                   help="seconds the body holds each pose before the cloth is recorded, so that it comes to rest "
                        "(quasi-static; 0: recorded as the body passes)")
    q.add_argument("--from-rest", action="store_true",
                   help="simulate every pose on its own from the rest drape (A-pose, blend, hold --settle), so that the "
                        "cloth depends on the pose alone and not on the path the sequence took to it")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--shard-size", type=int, default=16, help="sequences per shard file")
    _generator_args(q)
    q.set_defaults(func=_cmd_dataset_poses)
    b = kinds.add_parser("bodies", help="people of real-world shape photographed from several sides, with what the "
                                        "person finder sees in each picture (for the body from photos)")
    b.add_argument("--count", type=int, default=100, help="people (each photographed from 5 views)")
    b.add_argument("--genders", nargs="+", default=["female", "male"], choices=["female", "male"])
    b.add_argument("--bmi", type=float, nargs=2, default=[17.0, 40.0], metavar=("LOW", "HIGH"), help="BMI range (uniform)")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--shard-size", type=int, default=64, help="people per shard file")
    _generator_args(b)
    b.set_defaults(func=_cmd_dataset_bodies)
    c = kinds.add_parser("clips", help="short clips of a garment of a known fabric class on a moving body (for "
                                       "fabric from video)")
    c.add_argument("--garment", default="tshirt", help="tshirt, longsleeve, skirt, trousers or dress")
    c.add_argument("--sizes", nargs="+", default=["XS", "S", "M", "L", "XL", "XXL"],
                   help="standard sizes; each body wears its own (the nearest by the chart)")
    c.add_argument("--count", type=int, default=540, help="clips (the fabric classes take turns)")
    c.add_argument("--edge-length", type=float, default=0.03, help="garment triangle edge length in metres")
    c.add_argument("--frames", type=int, default=25, help="frames per clip")
    c.add_argument("--fps", type=float, default=5.0, help="frames per second of the clip")
    c.add_argument("--motions", nargs="+", default=["walk", "arm-raise", "turn"], help="built-in motions to draw from")
    c.add_argument("--genders", nargs="+", choices=["female", "male"],
                   help="default: female for skirt and dress, both for the other garments")
    c.add_argument("--bmi", type=float, nargs=2, default=[17.0, 38.0], metavar=("LOW", "HIGH"), help="BMI range (uniform)")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--shard-size", type=int, default=32, help="clips per shard file")
    c.add_argument("--presets", nargs="+", metavar="FABRIC",
                   help="measured fabrics taken in turn as measured, instead of fabrics drawn inside the classes "
                        "(held-out clips for tryon bench perceive)")
    _generator_args(c)
    c.set_defaults(func=_cmd_dataset_clips)
    k = kinds.add_parser("pack", help="a compact copy (float16 garment vertices) to keep in version control; "
                                       "packing again into it adds only what changed")
    k.add_argument("dataset", help="dataset folder")
    k.add_argument("--out", required=True, help="folder of the copy")
    k.add_argument("--force", action="store_true",
                   help="replace an --out that is not an earlier pack of this dataset (another dataset or pack, a pack "
                        "made before packs were marked, one holding other files, or a folder tryon did not write)")
    k.add_argument("--splits", nargs="+", metavar="SPLIT",
                   help="keep only these splits' samples (e.g. test extrapolation: what a model ships to be judged on)")
    k.set_defaults(func=_cmd_dataset_pack)
