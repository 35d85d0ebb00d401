"""`tryon bench body`: the body from photos on the photo dataset's held-out people.

The test people of a photo dataset (`tryon dataset bodies`; default `data/bodies-v1`, the
one the shipped model was trained on) are seen through 1, 2 and 4 of their views (front;
front and left; front, back, left and right), as BlazePose saw them when the data was
made. Methods, side by side:

* `photos`: the network's reading (`read_error_pct`) and the body Anny is fitted to from it
  (`per_measurement_pct`, `measurement_error_pct`, `vertex_error_cm`), with the weight given;
* `photos-no-weight`: the same when the shopper gives stature and gender only;
* `height-weight`: `fit_body` from stature, weight, gender and age (the ANSUR II prior
  fills in the rest), what tryon builds without photos;
* `mean`: the training people's mean measurements and mean Anny shape, per gender.

Keys: `views`, `clothing`, `method`, `measurement_error_pct` (mean relative error over
chest, waist at the navel and hip), `per_measurement_pct` (dict), `vertex_error_cm` (mean
vertex distance between the A-posed bodies after their centroids are aligned),
`inference_ms` (the network, per person), `fit_s`, `people`.

With `drapes` > 0, that many test people are also photographed from four sides
(`tryon.dataset.photos.photograph`), their body estimated from those four renders with the
weight given (`body_from_photos`, the person finder included), and a T-shirt M draped on
the estimated and on the true body: records with `method` `tshirt-drape` give the mean
surface distance between the two drapes (`surface_distance_cm`, both ways), and a picture
of each pair is written next to the JSON.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tryon.bench.records import one_torch_thread, write_records
from tryon.errors import TryonError

GIRTHS = ("chest", "waist_navel", "hip")
DEFAULT_DATA = Path("data/bodies-v1")


def _a_pose_vertices(shape) -> np.ndarray:
    from tryon.body.pose import posed_body

    v = posed_body(shape, "a").vertices
    return v - v.mean(0)


def _vertex_error_cm(shape, truth: np.ndarray) -> float:
    return float(100.0 * np.linalg.norm(_a_pose_vertices(shape) - truth, axis=1).mean())


def _true_shape(vector: np.ndarray):
    from tryon.body.anny_model import body_model
    from tryon.dataset.drapes import shape_params

    return body_model().rest_shape(shape_params(vector))


def _errors(pred: dict[str, float], truth: np.ndarray, names: list[str]) -> dict[str, float]:
    return {n: 100.0 * abs(pred[n] - truth[i]) / truth[i] for i, n in enumerate(names) if n in pred}


def _summary(rows: list[dict], names: list[str]) -> dict:
    per = {n: round(float(np.mean([r[n] for r in rows if n in r])), 3) for n in names if any(n in r for r in rows)}
    return {"per_measurement_pct": per, "measurement_error_pct": round(float(np.mean([per[g] for g in GIRTHS])), 3)}


def _surface_distance_cm(a_v: np.ndarray, b_v: np.ndarray, faces: np.ndarray) -> float:
    """Mean distance from each drape's vertices to the other drape's surface (cm)."""
    from tryon.sim.geometry import nearest_surface_points

    d1 = np.abs(nearest_surface_points(a_v, b_v, faces)[0])
    d2 = np.abs(nearest_surface_points(b_v, a_v, faces)[0])
    return float(100.0 * 0.5 * (d1.mean() + d2.mean()))


def drape_comparison(json_path: str, t, rows: np.ndarray, model, count: int) -> list[dict]:
    """A T-shirt M on the body from four renders and on the true body, for `count` people."""
    from tryon.dataset.photos import photograph
    from tryon.drape import DrapeRequest, drape
    from tryon.drape.outputs import render_views
    from tryon.learn.body_from_photos import body_from_photos
    from tryon.render.offscreen import save_png

    records = []
    from tryon.body.fit import Measurements

    for r in rows[np.linspace(0, len(rows) - 1, min(count, len(rows))).round().astype(int)]:
        gender = "female" if t.gender[r] else "male"
        shape = _true_shape(t.shape[r])
        photos = photograph(shape, ("front", "left", "back", "right"), seed=int(r))
        body = Measurements(height_cm=float(t.height[r]), weight_kg=float(t.weight[r]), gender=gender,
                            age=float(t.age[r]))
        req = DrapeRequest(body, garment="tshirt", size="M", fabric="gray-interlock", allow_tight=True)
        try:
            pb = body_from_photos([(f"view-{i}", p) for i, p in enumerate(photos)], float(t.height[r]), gender,
                                  float(t.weight[r]), float(t.age[r]), model)
            on_true = drape(req, progress=False, person=_fit_of_shape(shape, body))
            on_photo = drape(req, progress=False, person=pb.fit)
        except TryonError as exc:  # a render the finder refuses, a drape the simulator cannot make: counted
            records.append({"views": 4, "clothing": "tight", "method": "tshirt-drape", "person": int(r),
                            "failed": str(exc)[:300]})
            print(f"person {int(r)}: no comparison ({str(exc)[:120]})")
            continue
        faces = on_true.garment.faces
        dist = _surface_distance_cm(on_true.x, on_photo.x, faces)
        pics = [render_views(d.body_vertices, d.body_faces, d.x, faces, size=(300, 400), views=("front", "side"))
                for d in (on_true, on_photo)]
        picture = Path(json_path).with_name(f"{Path(json_path).stem}-tshirt-{int(r)}.png")
        save_png(picture, _captioned(np.concatenate([np.concatenate(p, 1) for p in pics], 1),
                                     ["on the true body", f"on the body from 4 photos: {dist:.2f} cm apart"]))
        records.append({"views": 4, "clothing": "tight", "method": "tshirt-drape", "person": int(r),
                        "surface_distance_cm": round(dist, 3), "settled": bool(on_true.metrics.get("settled")) and
                        bool(on_photo.metrics.get("settled")), "picture": picture.name,
                        "hip_error_pct": round(100 * abs(pb.read.tapes["hip"] - t.tapes[r][t.tape_names.index("hip")])
                                               / t.tapes[r][t.tape_names.index("hip")], 2),
                        "from_photos_s": round(pb.timings["total_s"], 2)})
        print(f"person {int(r)}: T-shirt M on the body from 4 renders is {dist:.2f} cm from the one on the true body")
    return records


def _captioned(image: np.ndarray, captions: list[str]) -> np.ndarray:
    """Each caption over its equal share of the picture's width, at the top."""
    from PIL import Image, ImageDraw

    from tryon.render.colormap import label_font

    pil = Image.fromarray(image)
    draw = ImageDraw.Draw(pil)
    font = label_font(max(12, image.shape[0] // 28))
    share = image.shape[1] / len(captions)
    for i, text in enumerate(captions):
        draw.text((i * share + 10, 8), text, fill=(20, 20, 20), font=font)
    return np.asarray(pil)


def _fit_of_shape(shape, body):
    """A `BodyFit` of a known shape (the dataset's true body), measured by the tapes."""
    from tryon.body.fit import BodyFit
    from tryon.body.measure import measurements
    from tryon.body.tape import tape_measurements

    achieved = measurements(shape)
    achieved.update({k: v for k, v in tape_measurements(shape).items() if k != "height_cm"})
    return BodyFit(shape, shape.params, {"height_cm": body.height_cm, "weight_kg": body.weight_kg}, achieved, 0, 0.0)


def run_body_bench(json_path: str, data: str | Path | None = None, model: str | Path | None = None,
                   people: int | None = 60, views: tuple[int, ...] = (1, 2, 4), drapes: int = 0) -> list[dict]:
    from tryon.body.fit import Measurements, fit_body
    from tryon.learn.train_body_photos import Standards, load_photo_tensors, predict, view_subsets
    from tryon.learn.body_from_photos import fit_read_body, shipped_model, weight_in_range
    from tryon.learn.body_photos import WEIGHT_TAPES

    data = Path(data) if data is not None else DEFAULT_DATA
    net = shipped_model(model)
    manifest, t = load_photo_tensors(data)
    trained_on = net.card.get("manifest", {})
    if trained_on and trained_on.get("seed") != manifest.seed:
        raise TryonError(f"{data} (seed {manifest.seed}) is not the dataset the model was trained on "
                         f"(seed {trained_on.get('seed')}): its test people may be training people")
    rows = t.rows("test")
    if people is not None:
        rows = rows[np.linspace(0, len(rows) - 1, min(people, len(rows))).round().astype(int)]
    if not len(rows):
        raise TryonError(f"{data} has no test people")
    train = t.rows("train")
    std = Standards(net.baseline, net.weight, np.zeros(1), np.ones(1))
    gender_name = {0.0: "male", 1.0: "female"}
    truth_v = {}
    out: dict[tuple, list] = {}
    times: dict[tuple, list] = {}
    subsets = {n: s for n, s in view_subsets(t).items() if n in views}
    with one_torch_thread():
        for r in tqdm(rows, desc="bench body", unit="person"):
            truth = t.tapes[r]
            truth_v[r] = _a_pose_vertices(_true_shape(t.shape[r]))
            g = gender_name[float(t.gender[r])]
            t0 = time.perf_counter()
            with one_torch_thread():  # again: the posed bodies' collision queries reset torch's threads
                hw = fit_body(Measurements(height_cm=float(t.height[r]), weight_kg=float(t.weight[r]), gender=g,
                                           age=float(t.age[r])))
            hw_s = time.perf_counter() - t0
            row = {**_errors({k[:-3]: v for k, v in hw.achieved.items()}, truth, t.tape_names),
                   "vertex": _vertex_error_cm(hw.shape, truth_v[r]), "fit_s": hw_s}
            for n in subsets:
                out.setdefault((n, "height-weight"), []).append(row)
            for n, vs in subsets.items():
                for method, given in (("photos", True), ("photos-no-weight", False)):
                    t0 = time.perf_counter()
                    read = predict(net.net, t, np.array([r]), std, vs, given)[0]
                    ms = 1000.0 * (time.perf_counter() - t0)
                    tapes = dict(zip(t.tape_names, (float(x) for x in read)))
                    weight = float(t.weight[r]) if given else weight_in_range(float(t.height[r]), g, float(
                        net.weight.from_girths(t.height[r], t.gender[r], np.array([[tapes[k] for k in WEIGHT_TAPES]]))[0]),
                        [])
                    t0 = time.perf_counter()
                    fit, _ = fit_read_body(float(t.height[r]), g, weight, float(t.age[r]), tapes, [])
                    fit_s = time.perf_counter() - t0
                    out.setdefault((n, method), []).append(
                        {**_errors({k[:-3]: v for k, v in fit.achieved.items()}, truth, t.tape_names),
                         "vertex": _vertex_error_cm(fit.shape, truth_v[r]), "fit_s": fit_s,
                         "read": _errors(tapes, truth, t.tape_names)})
                    times.setdefault((n, method), []).append(ms)
        # the mean body: the training people's mean tapes and mean shape, per gender
        for gcode in (0.0, 1.0):
            mine = train[t.gender[train] == gcode]
            if not len(mine):
                continue
            mean_tapes = dict(zip(t.tape_names, t.tapes[mine].mean(0)))
            mean_shape = _true_shape(t.shape[mine].mean(0))
            for r in rows[t.gender[rows] == gcode]:
                row = {**_errors(mean_tapes, t.tapes[r], t.tape_names), "vertex": _vertex_error_cm(mean_shape, truth_v[r]),
                       "fit_s": 0.0}
                for n in subsets:
                    out.setdefault((n, "mean"), []).append(row)
    records = []
    for (n, method), rs in sorted(out.items()):
        rec = {"views": n, "clothing": manifest.spec.get("clothing", "tight"), "method": method,
               **_summary(rs, t.tape_names), "vertex_error_cm": round(float(np.mean([x["vertex"] for x in rs])), 3),
               "fit_s": round(float(np.mean([x["fit_s"] for x in rs])), 3), "people": len(rs)}
        if (n, method) in times:
            rec["inference_ms"] = round(float(np.median(times[(n, method)])), 2)
            read = _summary([x["read"] for x in rs], t.tape_names)
            rec["read_error_pct"] = read["measurement_error_pct"]
            rec["read_per_measurement_pct"] = read["per_measurement_pct"]
        records.append(rec)
    meta = {"bench": "body", "data": str(data), "model": str(model or "shipped"), "test_people": int(len(rows))}
    write_records(json_path, records, **meta)  # kept even if a drape below fails
    _print_table(records)
    if drapes:
        with one_torch_thread():
            records += drape_comparison(json_path, t, rows, model, drapes)
        write_records(json_path, records, **meta)
    return records


def _print_table(records: list[dict]) -> None:
    print(f"{'views':>5s} {'method':18s} {'girths %':>8s} {'chest':>6s} {'waist':>6s} {'hip':>6s} {'read %':>7s} "
          f"{'vertex cm':>9s} {'ms':>6s}")
    for r in records:
        if "per_measurement_pct" not in r:
            continue
        p = r["per_measurement_pct"]
        read = f"{r['read_error_pct']:.2f}" if "read_error_pct" in r else ""
        ms = f"{r['inference_ms']:.1f}" if "inference_ms" in r else ""
        print(f"{r['views']:5d} {r['method']:18s} {r['measurement_error_pct']:8.2f} {p['chest']:6.2f} "
              f"{p['waist_navel']:6.2f} {p['hip']:6.2f} {read:>7s} {r['vertex_error_cm']:9.2f} {ms:>6s}")
