"""What a worker process does with one phase of a fit (`tryon.serve.store.PHASES`),
each answer written to the store as it comes, with the files the page and the API serve
under `<data>/fits/<fit_id>/`:

- `answer`: every size predicted and judged (`tryon.sizing.quick.first_answer`), the
  recommendation and, per size, the scene the page draws; status `predicted`.
- `refine`: the sizes that decide refined by the simulator (`refine_decisive`), each with
  its fit map PNG, GLB and scene; status `refined`.
- `simulate` (garments without a learned model): every size simulated, status `simulated`.

The body is the one fitted when it was posted (`bodies.load_body`), never fitted again.
"""

from __future__ import annotations

import math
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from tryon.serve.bodies import load_body
from tryon.serve.scene import SceneArrays, write_scene
from tryon.serve.store import Store
from tryon.sizing.judge import ease_of

# sizes simulated when a garment has no learned model and the request names none
SIMULATED_SIZES = ("S", "M", "L", "XL")
# a refinement worker yields the processor to first answers (nice value, 0-19)
REFINE_NICENESS = 10


def fit_folder(data: Path, fit_id: str) -> Path:
    return data / "fits" / fit_id


def body_path(data: Path, body_id: str) -> Path:
    return data / "bodies" / f"{body_id}.pkl"


@lru_cache(maxsize=64)
def _person(path: str):
    return load_body(path)


def learned_garment(garment: str) -> bool:
    from tryon.learn.model import shipped_model_path

    return shipped_model_path(garment).is_file()


def first_phase(garment: str) -> str:
    return "answer" if learned_garment(garment) else "simulate"


def run_phase(db: str, data: str, fit_id: str, phase: str) -> str:
    """Run one phase of fit `fit_id`; returns the fit's status after it. Any error fails
    the fit with the error's message (a worker that dies is caught by the dispatcher)."""
    from tryon.errors import TryonError
    from tryon.io.threads import one_torch_thread
    from tryon.parallel.executors import one_thread_per_worker

    one_thread_per_worker()  # a Ray worker's too
    store = Store(db)
    try:
        row = store.fit(fit_id)
        if row is None:  # forgotten meanwhile (retention): nothing to do
            return "missing"
        body = store.body(row.body_id)
        if body is None:
            raise TryonError(f"the body {row.body_id} is no longer kept; post it again")
        body_request = body[0]
        with one_torch_thread():
            person = _person(str(body_path(Path(data), row.body_id)))
            run = {"answer": _answer, "refine": _refine, "simulate": _simulate}[phase]
            return run(store, Path(data), fit_id, body_request, row.request, person)
    except TryonError as exc:
        store.update(fit_id, "failed", 1.0, reason=str(exc)[:500])
        return "failed"
    except Exception as exc:  # noqa: BLE001 - a job's bug must not take the worker down; its reason is kept
        store.update(fit_id, "failed", 1.0, reason=f"internal error: {type(exc).__name__}: {str(exc)[:300]}")
        return "failed"


def _first(body_request: dict, req: dict, person):
    from tryon.fabric import load_fabric
    from tryon.sizing.quick import first_answer

    return first_answer(person, body_request["gender"], req["garment"], req.get("sizes"), fabric=load_fabric(req["fabric"]))


def _answer(store: Store, data: Path, fit_id: str, body_request: dict, req: dict, person) -> str:
    t0 = time.perf_counter()
    first = _first(body_request, req, person)
    folder = fit_folder(data, fit_id)
    sizes = []
    for p in first.sizes:
        tag = f"{p.size}-predicted"
        write_scene(folder, tag, SceneArrays(p.x, p.garment.faces, first.body.vertices, first.body.faces, p.strain,
                                             None, p.skin_distance), req["fabric"])
        sizes.append(dict(_size_entry(p.judged), scene_url=f"/v1/files/{fit_id}/{tag}-scene.json"))
    _keep_answer(folder, first)
    result = {"recommended": first.recommended, "reasons": first.reasons, "method": "learned", "sizes": sizes,
              "notes": first.notes, "timings": {"answer_s": round(time.perf_counter() - t0, 3)}}
    store.update(fit_id, "predicted", 0.3, result=result)
    store.next_phase(fit_id, "refine")
    return "predicted"


def _refine(store: Store, data: Path, fit_id: str, body_request: dict, req: dict, person) -> str:
    from tryon.body.fit import Measurements
    from tryon.drape.pipeline import DrapeRequest
    from tryon.sizing.quick import refine_decisive

    t0 = time.perf_counter()
    folder = fit_folder(data, fit_id)
    first = _kept_answer(folder) or _first_as_kept(_first(body_request, req, person))
    files: dict[str, dict] = {}
    previous = store.fit(fit_id).result or {}

    def on_refined(size: str, result) -> None:
        files[size] = _write_size_files(fit_id, result, folder, f"{size}-refined")
        store.update(fit_id, "predicted", min(0.95, 0.3 + 0.3 * len(files)), result=previous)

    request = DrapeRequest(Measurements(**body_request), garment=req["garment"], fabric=req["fabric"])
    best, reasons, judged, _ = refine_decisive(first["predicted"], first["recommended"], person, request,
                                               on_refined=on_refined)
    sizes = []
    for j in judged:
        entry = _size_entry(j)
        entry.update(files.get(j["size"]) or {"scene_url": f"/v1/files/{fit_id}/{j['size']}-predicted-scene.json"})
        sizes.append(entry)
    timings = {**previous.get("timings", {}), "refine_s": round(time.perf_counter() - t0, 3),
               "refined_sizes": len(files)}
    store.update(fit_id, "refined", 1.0, result={"recommended": best, "reasons": reasons, "method": "learned+refine",
                                                 "sizes": sizes, "notes": first["notes"], "timings": timings})
    return "refined"


ANSWER_FILE = "answer.pkl"


def _first_as_kept(first) -> dict:
    """What the refinement needs of a first answer."""
    return {"predicted": [p.judged for p in first.sizes], "recommended": first.recommended, "notes": first.notes}


def _keep_answer(folder: Path, first) -> None:
    """The first answer's judgements, for the refinement to start from (not predicted again)."""
    import pickle

    from tryon.io.atomic import atomic_write

    folder.mkdir(parents=True, exist_ok=True)
    with atomic_write(folder / ANSWER_FILE, "wb") as fh:
        pickle.dump(_first_as_kept(first), fh, protocol=pickle.HIGHEST_PROTOCOL)


def _kept_answer(folder: Path) -> dict | None:
    import pickle

    try:
        with open(folder / ANSWER_FILE, "rb") as fh:
            return pickle.load(fh)  # noqa: S301 - written by the answer phase of this service
    except Exception:  # noqa: BLE001 - missing or unreadable: the answer is predicted again
        return None


def _simulate(store: Store, data: Path, fit_id: str, body_request: dict, req: dict, person) -> str:
    from tryon.body.fit import Measurements
    from tryon.sizing.recommend import size_recommendation

    t0 = time.perf_counter()
    rec, results = size_recommendation(Measurements(**body_request), garment=req["garment"], fabric=req["fabric"],
                                       method="simulate", sizes=req.get("sizes") or list(SIMULATED_SIZES),
                                       person=person)
    folder = fit_folder(data, fit_id)
    sizes = []
    for j, r in zip(rec["sizes"], results):
        entry = _size_entry(j)
        if not isinstance(r, str):  # a size the simulator could draw
            entry.update(_write_size_files(fit_id, r, folder, f"{j['size']}-simulated"))
        sizes.append(entry)
    store.update(fit_id, "simulated", 1.0, result={"recommended": rec["recommended"], "reasons": rec["reasons"],
                                                   "method": rec["method"], "sizes": sizes, "notes": rec["notes"],
                                                   "timings": {"simulate_s": round(time.perf_counter() - t0, 3)}})
    return "simulated"


def _number(x) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else round(float(x), 3)


def _size_entry(judged: dict) -> dict:
    """What the API says of one size's judgement."""
    regions = judged.get("regions", {})
    pressures = [r["mean_pressure_kpa"] for r in regions.values() if "mean_pressure_kpa" in r]
    return {"size": judged["size"], "fits": bool(judged["fits"]), "why_not": judged["why_not"],
            "ease_cm": _number(ease_of(judged)), "ease_at": judged.get("decided_by", "torso"),
            "overstretched_area_pct": _number(judged["overstrained_area_pct"]),
            "max_strain_pct": _number(judged["max_strain_pct"]),
            "pressure_kpa": _number(max(pressures)) if pressures else None,
            "judged_on": judged.get("judged_on", "simulated drape"), "not_refined": judged.get("not_refined"),
            "fit_map_url": None, "glb_url": None, "scene_url": None}


def _write_size_files(fit_id: str, result, folder: Path, tag: str) -> dict:
    """A drape's fit map PNG, GLB and scene; their URLs."""
    from tryon.drape.outputs import SKIN, fit_map_image
    from tryon.io.mesh_io import write_glb
    from tryon.render.appearance import appearance
    from tryon.render.offscreen import save_png
    from tryon.sim.geometry import nearest_surface_points

    folder.mkdir(parents=True, exist_ok=True)
    g, bv, bf = result.garment, result.body_vertices, result.body_faces
    strain = 100.0 * np.asarray(result.strain)
    save_png(folder / f"{tag}-fit_map.png", fit_map_image(bv, bf, result.x, g.faces, strain,
                                                          vmax=max(10.0, float(np.percentile(strain, 99))), label="strain %"))
    write_glb(folder / f"{tag}.glb", [(bv, bf, SKIN, "body"),
                                      (result.x, g.faces, appearance(str(result.request.fabric)).color, "garment")])
    d, _, _ = nearest_surface_points(result.x, bv, bf)
    write_scene(folder, tag, SceneArrays(result.x, g.faces, bv, bf, np.asarray(result.strain), np.asarray(result.pressure), d),
                str(result.request.fabric))
    return {"fit_map_url": f"/v1/files/{fit_id}/{tag}-fit_map.png", "glb_url": f"/v1/files/{fit_id}/{tag}.glb",
            "scene_url": f"/v1/files/{fit_id}/{tag}-scene.json"}
