"""`tryon bench fit-fabric`: fabric estimation on motion another simulator produced.

Each observation is a reference run of `tryon bench fidelity` (ARCSim 0.3.1: every run,
at dt 0.005 and at dt 0.02; `--quick`: the dt 0.005 runs) with everything but what a
camera could give removed: only ``positions``, ``faces``, ``uv``, ``pinned``,
``frame_time``, ``gravity`` and the wind keys remain (no ``dt``, no handle stiffness, no
fabric). `tryon fit-fabric` then has to choose its own time step, find that the corners
hang from soft handles, and estimate the fabric; its errors are measured against the
run's ground truth.

`HELD_OUT` fabrics (the seven measured fabrics that have no ARCSim run here) are observed
in the same scene as `tryon` simulates it with ARCSim's settings (soft handles, explicit
wind, dt 0.005): at its own time step `tryon` reproduces ARCSim to 0.00-0.12 % (`tryon
bench fidelity`), so these stand in for ARCSim runs of those fabrics.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from tryon.bench.fidelity import REFERENCE_DIR, ReferenceRun, load_reference_runs
from tryon.bench.records import one_torch_thread, write_records
from tryon.diff.fit import run_fit_fabric
from tryon.diff.observed import Observation, camera_only, save_observed, simulate_frames
from tryon.fabric.presets import load_fabric

HELD_OUT = ("11oz-black-denim", "camel-ponte-roma", "ivory-rib-knit", "navy-sparkle-sweat", "royal-target",
            "tango-red-jet-set", "white-swim-solid")
REFERENCE_DT = 0.005
SCENE_RUN = "gray-interlock_dt0.005"  # the ARCSim run whose scene the held-out observations reuse


def held_out_observation(scene: ReferenceRun, fabric: str) -> Observation:
    """The ARCSim scene of `scene` with another fabric, simulated by tryon at dt 0.005."""
    obs = scene.obs
    spf = int(round(obs.frame_time / REFERENCE_DT))
    x = simulate_frames(obs.model(load_fabric(fabric)), obs.num_frames, spf, obs.frame_time / spf)
    return Observation(x, obs.faces, obs.uv, obs.pinned, obs.frame_time, obs.gravity, obs.wind_velocity,
                       obs.wind_density, obs.wind_drag, REFERENCE_DT, fabric, obs.handle_stiffness)


def _fit(name: str, obs: Observation, truth: str, source: str, folder: Path, out_dir: Path | None) -> dict:
    path = folder / f"{name}.npz"
    save_observed(path, camera_only(obs))
    out = (out_dir / name) if out_dir else folder / f"{name}-fit"
    report = run_fit_fabric(str(path), str(out), truth=truth, progress=False, force=True)
    keys = ("density_error", "stretching_error", "bending_error", "simulation_error", "simulation_error_at_truth",
            "start_simulation_error", "simulations", "simulated_steps", "wall_s", "dt", "handles", "handle_stiffness")
    rec = {"observation": name, "source": source, "truth": truth, **{k: report.get(k) for k in keys}}
    ident = report.get("identifiability", {})
    rec["determined_groups"] = [g for g, v in ident.get("groups", {}).items() if v["determined"]]
    rec["identifiability_wall_s"] = ident.get("wall_s")
    rec["density_from_momentum"] = report.get("momentum_balance", {}).get("density_kg_m2")
    return rec


def _print_table(records: list[dict]) -> None:
    print(f"{'observation':30s} {'dt':>6s} {'density':>8s} {'sim err':>8s} {'at truth':>8s} {'sims':>5s} {'wall s':>7s}")
    for r in records:
        print(f"{r['observation']:30s} {r['dt']:6.4f} {100 * r['density_error']:7.2f}% {100 * r['simulation_error']:7.2f}% "
              f"{100 * r['simulation_error_at_truth']:7.2f}% {r['simulations']:5d} {r['wall_s']:7.1f}")
    for source in dict.fromkeys(r["source"] for r in records):
        rows = [r for r in records if r["source"] == source]
        d = 100 * np.array([r["density_error"] for r in rows])
        e = 100 * np.array([r["simulation_error"] for r in rows])
        print(f"{source} ({len(rows)}): density error {d.mean():.2f} +- {_sample_std(d):.2f} %, simulation error "
              f"{e.mean():.2f} +- {_sample_std(e):.2f} % (max {e.max():.2f} %)")


def _sample_std(a: np.ndarray) -> float:
    return float(a.std(ddof=1)) if len(a) > 1 else 0.0


def run_fit_fabric_bench(json_path: str, reference: str | None = None, held_out: tuple[str, ...] = HELD_OUT,
                         all_steps: bool = True, keep: bool = True) -> list[dict]:
    """Fit every observation (module docstring; `all_steps` False: only the dt 0.005 runs);
    write the records as JSON, with the fit folders next to it (``<stem>-fits/``) when `keep`."""
    with one_torch_thread():
        return _run(json_path, reference, held_out, all_steps, keep)


def _run(json_path: str, reference: str | None, held_out: tuple[str, ...], all_steps: bool, keep: bool) -> list[dict]:
    runs = load_reference_runs(reference or REFERENCE_DIR)
    chosen = [r for r in runs if all_steps or np.isclose(r.obs.dt, REFERENCE_DT)]
    out = Path(json_path)
    fits_dir = out.with_name(f"{out.stem}-fits") if keep else None
    records: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for run in chosen:
            records.append(_fit(run.name, run.obs, run.fabric.name, f"ARCSim 0.3.1 at dt {run.obs.dt:g}", folder,
                                fits_dir))
            print(json.dumps(records[-1]), flush=True)
        scene = next((r for r in runs if r.name == SCENE_RUN), runs[0])
        with_runs = {r.fabric.name for r in runs}
        for fabric in held_out:
            if fabric in with_runs:
                print(f"{fabric}: has an ARCSim run here, so it is not held out", flush=True)
                continue
            obs = held_out_observation(scene, fabric)
            records.append(_fit(f"{fabric}_dt{REFERENCE_DT}", obs, fabric, "tryon in ARCSim's scene (held out)", folder,
                                fits_dir))
            print(json.dumps(records[-1]), flush=True)
    _print_table(records)
    write_records(json_path, records)
    return records
