"""`tryon bench print`: does a model trained on plain shirts adapt to a print by refinement?

For test bodies of a drape dataset, the shirt is simulated again with a print on its front
(`tryon.garment.prints`: heavier and stiffer cloth where the ink lies); that is the truth.
The learned model knows nothing of prints. Its prediction is refined by the simulator
twice: with the print's material and without. One record per method, against the printed
simulation: mean vertex error over the garment and over the printed faces' vertices (cm),
the potential (gravity + stretching + bending with the print's material) and its elastic
part alone (gravity, measured from the floor, dominates the total) relative to the printed
simulation's, the share of vertices inside the body, and seconds. The record
`simulated plain` is the dataset's own drape: how far the print moves the shirt at all;
`print_fold_deg` (the mean bend of the printed area's hinges) says how wrinkled the
printed area is in each.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from tryon.bench.records import write_records
from tryon.errors import TryonError


def logo_image(rows: int = 200, cols: int = 240) -> np.ndarray:
    """A test print [rows, cols, 4] (uint8): a red ring crossed by a yellow bar, transparent
    elsewhere, so the printed area has holes and edges like a real graphic."""
    yy, xx = np.mgrid[:rows, :cols]
    r = np.hypot(xx - cols / 2, yy - rows / 2) / (0.5 * min(rows, cols))
    im = np.zeros((rows, cols, 4), np.uint8)
    im[(r < 0.9) & (r > 0.6)] = (220, 40, 40, 255)
    im[(np.abs(xx - cols / 2) < 0.33 * cols) & (np.abs(yy - rows / 2) < 0.06 * rows)] = (250, 220, 30, 255)
    return im


def _fold_deg(cloth, x: np.ndarray, hinges: np.ndarray) -> float:
    """Mean absolute bend (degrees, from the rest angle) over the hinges in the print: how
    wrinkled the printed area is."""
    from tryon.sim.forces.bending import dihedral_angle

    theta = dihedral_angle(torch.from_numpy(np.ascontiguousarray(x)), cloth.hinges) - cloth.hinge_rest_theta
    return float(np.degrees(np.abs(theta.numpy()[hinges])).mean())


def _picture(path: Path, garment, body, req, fabric: str, drapes: dict[str, np.ndarray]) -> None:
    """Front views of the torso, one per drape, the print drawn on each."""
    from tryon.drape.outputs import SKIN, garment_look
    from tryon.render.offscreen import Camera, RenderMesh, render_meshes, save_png

    pr = req.graphic_print(garment)
    tiles = []
    for title, x in drapes.items():
        v, f, c, n = garment_look(garment, x, fabric, pr)
        cam = Camera.fit([x], "front", aspect=0.8, margin=1.1)
        img = render_meshes([RenderMesh(body.vertices, body.faces, color=SKIN, two_sided=False),
                             RenderMesh(v, f, vertex_colors=c, vertex_normals=n)], 480, 600, camera=cam)
        tiles.append(_titled(img, title))
    save_png(path, np.concatenate(tiles, axis=1))


def _titled(img: np.ndarray, title: str) -> np.ndarray:
    from PIL import ImageDraw

    im = Image.fromarray(img)
    ImageDraw.Draw(im).text((10, 10), title, fill=(0, 0, 0))
    return np.asarray(im)


def _sample_request(data, row: int, png: Path, width_cm: float):
    from tryon.dataset.bodies import BodyRanges, sample_body
    from tryon.dataset.drapes import DATASET_DRAPE
    from tryon.drape.pipeline import DrapeRequest

    spec = data.manifest.spec
    body = sample_body(data.manifest.seed, int(data.arrays["body"][row]), BodyRanges.from_dict(spec["ranges"]))
    size = spec["sizes"][int(data.arrays["size"][row])]
    return body, DrapeRequest(body.measurements(), garment=spec["garment"], size=size, fabric=spec["fabric"],
                              edge_length=spec["edge_length"], print_image=str(png), print_width_cm=width_cm, **spec["drape"],
                              **DATASET_DRAPE)


def run_print_bench(json_path: str | Path, data_dir: str | Path, model_path: str | Path | None = None, count: int = 4,
                    width_cm: float = 24.0, progress: bool = True) -> list[dict]:
    from tryon.dataset.drapes import build_references
    from tryon.dataset.loading import load_drape_dataset
    from tryon.drape.fit_metrics import penetration, potential_energy
    from tryon.drape.pipeline import simulate_drape
    from tryon.fabric import load_fabric
    from tryon.learn.data import GENDERS, training_set
    from tryon.learn.features import a_posed_body
    from tryon.learn.model import DrapeModel, load_shipped
    from tryon.learn.refine import refine_drape
    from tryon.learn.train import predict_set
    from tryon.dataset.drapes import shape_params
    from tryon.sim.model import ClothModel

    json_path = Path(json_path)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    png = json_path.parent / "print.png"
    Image.fromarray(logo_image()).save(png)
    data = load_drape_dataset(data_dir)
    if data.manifest.spec.get("fabrics"):
        raise TryonError(f"{data_dir} draws its fabric per drape; tryon bench print compares drapes of one fabric: "
                         "give a dataset made without --fabrics")
    model = DrapeModel.load(model_path) if model_path else load_shipped(data.manifest.spec["garment"])
    model.check_dataset(data.manifest.spec)
    ts = training_set(data, model.priors, model.region, progress=False)
    test = ts.subset(ts.split == "test")
    test = test.subset(np.arange(min(count, len(test.rows))))
    refs = build_references(data.manifest, Path(data_dir), progress=False)
    fabric = load_fabric(data.manifest.spec["fabric"])
    learned = predict_set(model, test)
    per: dict[str, list[dict]] = {}
    for i, row in enumerate(test.rows):
        t0 = time.perf_counter()
        body, req = _sample_request(data, int(row), png, width_cm)
        gender, size = GENDERS[int(test.gender[i])], req.size
        garment = model.reference_garment(gender, size)
        regions = req.material_regions(garment)
        printed_vertices = np.unique(garment.faces[np.asarray(regions[0].faces)])
        target = a_posed_body(shape_params(test.shape[i]))
        ref = refs[(gender, size)]
        truth, _, _, stats, _ = simulate_drape(req, ref.garment, ref.pose(), target, progress=False)
        sim_s = time.perf_counter() - t0
        pred = learned[i].astype(float)
        plain, plain_stats = refine_drape(pred, garment, target, fabric)
        inked, ink_stats = refine_drape(pred, garment, target, fabric, regions=regions)
        cloth = ClothModel(garment.cloth_mesh(), fabric, regions=regions)
        e_truth = potential_energy(cloth, truth)
        elastic = lambda e: e["membrane_J"] + e["bending_J"]  # noqa: E731
        printed_hinges = (cloth.hinge_bend_scale > 1.0).numpy()
        plain_sim = test.truth[i].astype(float)
        for method, x, secs in (("simulated print", truth, sim_s), ("simulated plain", plain_sim, float(data.arrays["wall_s"][row])),
                                ("learned", pred, 0.0), ("learned+refine plain", plain, plain_stats["refine_s"]),
                                ("learned+refine print", inked, ink_stats["refine_s"])):
            err = 100.0 * np.linalg.norm(x - truth, axis=1)
            per.setdefault(method, []).append({
                "mean_error_cm": float(err.mean()), "print_error_cm": float(err[printed_vertices].mean()),
                "potential_ratio": potential_energy(cloth, x)["total_J"] / e_truth["total_J"],
                "elastic_ratio": elastic(potential_energy(cloth, x)) / elastic(e_truth),
                "print_fold_deg": _fold_deg(cloth, x, printed_hinges),
                "interpenetration_pct": penetration(x, target.vertices, target.faces)["penetration_pct"],
                "seconds": secs, "simulation_s": sim_s, "settled": bool(stats["settled"])})
        if i == 0:
            _picture(json_path.with_suffix(".png"), garment, target, req, fabric.name,
                     {"learned": pred, "learned + refine with the print": inked, "simulated with the print": truth})
        if progress:
            print(f"print bench: body {i + 1}/{len(test.rows)} ({gender}, {size}, BMI {body.bmi:.1f}): the print moves the "
                  f"shirt {per['simulated plain'][-1]['print_error_cm']:.2f} cm under it; refined with it "
                  f"{per['learned+refine print'][-1]['print_error_cm']:.2f} cm, without "
                  f"{per['learned+refine plain'][-1]['print_error_cm']:.2f} cm", flush=True)
    records = []
    for method, rows in per.items():
        rec = {"method": method, "split": "test", "samples": len(rows), "print_width_cm": width_cm,
               "threads": torch.get_num_threads()}
        for key in ("mean_error_cm", "print_error_cm", "potential_ratio", "elastic_ratio", "print_fold_deg", "interpenetration_pct", "seconds",
                    "simulation_s"):
            rec[key] = float(np.mean([r[key] for r in rows]))
        rec["per_sample"] = rows
        records.append(rec)
    write_records(json_path, records)
    return records
