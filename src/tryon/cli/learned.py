"""`tryon train`: train the learned systems (tryon.learn, tryon.kdsm) on datasets from `tryon dataset`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _cmd_train_drape(args: argparse.Namespace) -> int:
    from tryon.errors import TryonError
    from tryon.learn.train import TrainConfig, train_drape

    if not 1 <= args.epochs <= 10_000 or not 1 <= args.batch <= 1024 or not 0 < args.lr < 1:
        raise TryonError("give 1-10000 epochs, a batch of 1-1024 and a learning rate between 0 and 1")
    config = TrainConfig(epochs=args.epochs, batch=args.batch, lr=args.lr, seed=args.seed)
    model = train_drape(list(args.data), args.out, config, progress=not args.quiet, force=args.force)
    print(json.dumps({"model": f"{args.out}/model.npz", "best_epoch": model.card["best_epoch"],
                      "metrics": model.card["metrics"]}, indent=1))
    return 0


def _cmd_train_kdsm(args: argparse.Namespace) -> int:
    from tryon.errors import TryonError
    from tryon.kdsm.train import KdsmTrainConfig, train_kdsm

    if args.smoothing is not None and args.method != "kdsm-hybrid":
        raise TryonError(f"--smoothing applies to kdsm-hybrid's targets only, not {args.method}'s")
    config = KdsmTrainConfig(method=args.method, epochs=args.epochs, batch=args.batch, lr=args.lr, seed=args.seed,
                             cell=args.cell, schedule=args.schedule, mirror=args.mirror,
                             **({} if args.smoothing is None else {"smoothing": args.smoothing}))
    config.validate()
    model = train_kdsm(args.data, args.out, config, progress=not args.quiet, force=args.force)
    print(json.dumps({"model": f"{args.out}/model.npz", "method": args.method, "metrics": model.card["metrics"]}, indent=1))
    return 0


def _cmd_train_body_photos(args: argparse.Namespace) -> int:
    from tryon.learn.train_body_photos import BodyTrainConfig, train_body_photos

    if args.epochs < 1 or args.batch < 1 or not args.lr > 0:
        from tryon.errors import TryonError

        raise TryonError("--epochs and --batch must be at least 1 and --lr positive")
    path = train_body_photos(args.data, args.out, BodyTrainConfig(args.epochs, args.batch, args.lr, args.seed),
                             progress=not args.quiet, force=args.force)
    print(f"model: {path} (card: {path.parent}/MODEL_CARD.md)")
    return 0


def _cmd_train_garment_codes(args: argparse.Namespace) -> int:
    from tryon.errors import TryonError
    from tryon.io.atomic import check_output_dir
    from tryon.learn.train_garment_codes import MODEL, CodeTrainConfig, train_garment_codes

    if args.epochs < 1 or args.batch < 1 or not args.lr > 0:
        raise TryonError("--epochs and --batch must be at least 1 and --lr positive")
    out = check_output_dir(args.out, force=args.force)
    card = train_garment_codes(args.data, out, CodeTrainConfig(args.epochs, args.batch, args.lr, args.seed),
                               progress=not args.quiet, force=args.force)
    print(json.dumps({"model": str(out / MODEL), "drapes": card["drapes"], "test": card["test"]}, indent=1))
    return 0


def _cmd_train_fabric_video(args: argparse.Namespace) -> int:
    from tryon.errors import TryonError
    from tryon.io.atomic import check_output_dir
    from tryon.learn.fabric_video import METHODS, clip_tensors
    from tryon.learn.train_fabric_video import ClassifierTrainConfig, train_classifier
    from tryon.learn.train_garment_codes import load_codes_model
    from tryon.perceive.fabric_classes import default_classes

    methods = list(METHODS) if args.method == "all" else [args.method]
    if args.method != "all" and args.method not in METHODS:
        raise TryonError(f"unknown method {args.method!r}; use all or one of {', '.join(METHODS)}")
    if args.epochs < 1 or args.batch < 1 or not args.lr > 0:
        raise TryonError("--epochs and --batch must be at least 1 and --lr positive")
    out = check_output_dir(args.out, force=args.force)
    codes, _ = load_codes_model(args.codes)
    clips = clip_tensors(args.data, codes, args.seed)
    classes = default_classes()
    results = {}
    for method in methods:
        card = train_classifier(clips, Path(out) / method, method, ClassifierTrainConfig(args.epochs, args.batch, args.lr,
                                                                                         args.seed),
                                classes.count, classes.distance, [str(d) for d in args.data], not args.quiet, args.force)
        results[method] = card["test"]
    print(json.dumps({"clips": card["clips"], "chance_top1": round(1 / classes.count, 4), "test": results}, indent=1))
    return 0


def _cmd_train_body_fit(args: argparse.Namespace) -> int:
    from tryon.body.amortised import MODEL_PATH
    from tryon.body.amortised_build import build, train
    from tryon.errors import TryonError

    if not 100 <= args.people <= 1_000_000 or not 1 <= args.epochs <= 100_000:
        raise TryonError("give 100 to 1,000,000 --people and 1-100000 --epochs")
    build(args.data, args.people, seed=args.seed, progress=not args.quiet)  # the fits not made yet
    out = args.out or MODEL_PATH
    model = train(args.data, out, epochs=args.epochs, check=args.check, progress=not args.quiet)
    print(json.dumps({"model": str(out), "unknowns_rms": model.card["unknowns_rms"], "check": model.card["check"]},
                     indent=1))
    return 0


def _training_options(p: argparse.ArgumentParser, epochs: int, batch: int, lr: float) -> None:
    """The options every `tryon train` kind with a model folder takes."""
    p.add_argument("--epochs", type=int, default=epochs)
    p.add_argument("--batch", type=int, default=batch)
    p.add_argument("--lr", type=float, default=lr)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--force", action="store_true", help="use an existing --out folder tryon did not write")


SHIPPED_CODES = Path(__file__).resolve().parents[1] / "learn" / "models" / "garment-codes.npz"


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register `tryon train ...` on the `tryon` parser."""
    t = sub.add_parser("train", help="train a learned model (checkpoints every epoch, resumes)")
    kinds = t.add_subparsers(dest="kind", required=True)
    p = kinds.add_parser("drape", help="the draping network on a drape dataset (tryon dataset drape)")
    p.add_argument("--data", required=True, nargs="+", metavar="DIR",
                   help="drape dataset folder(s): a simulated set, then any refined sets (tryon dataset refine) to add")
    p.add_argument("--out", required=True, help="model folder: model.npz, model_card.json, checkpoint.pt")
    _training_options(p, epochs=60, batch=4, lr=3e-3)
    p.set_defaults(func=_cmd_train_drape)
    b = kinds.add_parser("body-photos", help="the body from photos: the multi-view regression on a photo dataset "
                                             "(tryon dataset bodies)")
    b.add_argument("--data", required=True, help="photo dataset folder")
    b.add_argument("--out", required=True, help="model folder: model.npz, model_card.json, MODEL_CARD.md, checkpoint.pt")
    _training_options(b, epochs=60, batch=16, lr=1e-3)
    b.set_defaults(func=_cmd_train_body_photos)
    g = kinds.add_parser("garment-codes", help="fabric from video: the garment autoencoder (one latent space for "
                                               "every garment) on drape datasets")
    g.add_argument("--data", required=True, nargs="+", metavar="DIR", help="drape dataset folders, any garments")
    g.add_argument("--out", required=True, help="model folder: garment-codes.npz, model_card.json, checkpoint.pt")
    _training_options(g, epochs=40, batch=32, lr=1e-3)
    g.set_defaults(func=_cmd_train_garment_codes)
    v = kinds.add_parser("fabric-video", help="fabric from video: the fabric class from clips (tryon dataset clips), "
                                              "one method or every ablation")
    v.add_argument("--data", required=True, nargs="+", metavar="DIR", help="clip dataset folders")
    v.add_argument("--codes", default=str(SHIPPED_CODES), help="garment codes model (tryon train garment-codes)")
    v.add_argument("--method", default="image+garment-temporal",
                   help="image+garment, image-only or garment-only, each -temporal or -frame; or all")
    v.add_argument("--out", required=True, help="model folder (one subfolder per method)")
    _training_options(v, epochs=60, batch=16, lr=1e-3)
    v.set_defaults(func=_cmd_train_fabric_video)
    f = kinds.add_parser("body-fit", help="the amortised body fit: full fits of people across the range "
                                          "(resumable), then the network from measurements to Anny's unknowns")
    f.add_argument("--data", default="data/body-fits-v1", help="folder of the fits (made where missing)")
    f.add_argument("--people", type=int, default=3000, help="people to fit (about 1.3 s each)")
    f.add_argument("--out", help="model file (default: the shipped src/tryon/body/data/amortised_fit.npz)")
    f.add_argument("--epochs", type=int, default=3000)
    f.add_argument("--check", type=int, default=40, help="test people fitted both ways for the card")
    f.add_argument("--seed", type=int, default=0, help="the people's seed")
    f.add_argument("--quiet", action="store_true")
    f.set_defaults(func=_cmd_train_body_fit)
    k = kinds.add_parser("kdsm", help="pose-dependent cloth: the pixel network of one method on a pose dataset "
                                      "(tryon dataset poses)")
    k.add_argument("--data", required=True, help="pose dataset folder")
    k.add_argument("--method", default="kdsm-hybrid",
                   choices=["jin-uvn", "kdsm-method1", "kdsm-method2", "kdsm-hybrid"],
                   help="what the network predicts: Jin et al.'s surface offsets or the KDSM's d (three embeddings)")
    k.add_argument("--out", required=True, help="model folder: model.npz, model_card.json, checkpoint.pt")
    k.add_argument("--epochs", type=int, default=40)
    k.add_argument("--batch", type=int, default=16)
    k.add_argument("--lr", type=float, default=1e-3)
    k.add_argument("--seed", type=int, default=0)
    k.add_argument("--cell", type=float, default=0.02, help="the volume's lattice cell (m)")
    k.add_argument("--schedule", choices=["cosine", "constant"], default="cosine",
                   help="learning rate over the epochs: cosine decay to 5 %% of --lr, or constant (Jin et al.)")
    k.add_argument("--mirror", action="store_true",
                   help="add each training pose's left-right mirror image (the body and pattern are symmetric)")
    k.add_argument("--smoothing", type=float, default=None,
                   help="kdsm-hybrid only: screened-Poisson smoothing of its target d (each cloth vertex's "
                        "material-space offset) over the cloth mesh, default 0.25; 0 rebuilds the cloth exactly "
                        "wherever it lies in the posed volume (as Method 1), more gives smoother targets that "
                        "rebuild it less exactly")
    k.add_argument("--quiet", action="store_true")
    k.add_argument("--force", action="store_true", help="use an existing --out folder tryon did not write")
    k.set_defaults(func=_cmd_train_kdsm)
