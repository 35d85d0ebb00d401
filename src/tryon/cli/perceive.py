"""Commands that look at photos: `tryon person` (the person finder on your own pictures)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


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


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("person", help="find the person in photos (mask and keypoints, BlazePose): an overlay per "
                       "photo, or the reason it cannot be used")
    p.add_argument("images", nargs="+", metavar="IMG", help="photos (JPEG, PNG, ...) of one whole standing person")
    p.add_argument("--out", required=True, help="folder for the overlays and people.json")
    p.add_argument("--force", action="store_true", help="replace an --out folder tryon did not write")
    p.set_defaults(func=_cmd_person)
