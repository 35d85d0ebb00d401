"""`tryon bench fidelity`: `tryon` against ARCSim 0.3.1 on measured fabrics.

Every ARCSim run in the reference folder (``*.npz``: a hanging cloth in wind, ground
truth included; default: the copy in ``tryon/bench/reference/arcsim_wind``) is simulated
by `tryon` with the true fabric (the run's own ``material_*`` arrays and multipliers), and
compared frame by frame. The error is the mean vertex distance over frames 1..T-1 over
the cloth's diagonal (`tryon fit-fabric`'s simulation error). Records, with ``role``:

* ``own``: at the run's own time step, ARCSim's scene as ARCSim sets it up (soft node
  handles, explicit wind): the fidelity figure;
* ``cause``: the same step with one of ARCSim's settings replaced by `tryon`'s default
  (``without``: ``soft handles`` - the pinned corners held exactly; ``explicit wind`` -
  the wind's velocity Jacobian in the implicit solve; or both): each cause's share;
* ``dt``: at the other time steps of `DTS` (time-step bias);
* ``fit-fabric``: at the step `tryon fit-fabric` chooses for this observation from its
  frames alone (`tryon.diff.fit.prepare_fit`: the convergence check with the mean
  fabric at the density of the momentum balance);
* ``reference``: ARCSim against ARCSim, the same fabric at another time step, where the
  folder holds both (ARCSim's own time-step bias).

Pictures next to the JSON: ``<stem>-<run>.png``, error per frame for every record of the
run, and ``<stem>-<run>-frames.png``, ARCSim (top row), `tryon` at the run's step
(middle) and at fit-fabric's step (bottom) at 1/4, 1/2, 3/4 and the end.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tryon.bench.records import one_torch_thread, write_records
from tryon.diff.observed import Observation, camera_only, load_observed, simulate_frames
from tryon.diff.fit import prepare_fit
from tryon.errors import InputFileError, TryonError
from tryon.fabric.wang2011 import WangFabric
from tryon.io.atomic import atomic_path
from tryon.sim.model import ClothModel

REFERENCE_DIR = Path(__file__).resolve().parent / "reference" / "arcsim_wind"
DTS = (0.02, 0.01, 0.005, 0.0025)  # s: the steps every run is also simulated at
CAUSES = ("soft handles", "explicit wind", "soft handles and explicit wind")


@dataclass
class ReferenceRun:
    """One ARCSim run: the observation (scene and frames) and its true fabric."""

    name: str
    obs: Observation
    fabric: WangFabric


def true_fabric(path: Path) -> WangFabric:
    """The run's fabric from its ground-truth arrays, with ARCSim's load-time multipliers."""
    with np.load(path, allow_pickle=False) as data:
        missing = [k for k in ("material", "material_density", "material_stretching", "material_bending")
                   if k not in data]
        if missing:
            raise InputFileError(f"reference run {path}: missing ground-truth keys {missing}")
        mult = data["material_multipliers"] if "material_multipliers" in data else np.ones(3)
        raw = {"density": float(data["material_density"]), "stretching": data["material_stretching"].tolist(),
               "bending": data["material_bending"].tolist()}
        return WangFabric.from_arcsim_dict(raw, str(data["material"]), density_mult=float(mult[0]),
                                           stretching_mult=float(mult[1]), bending_mult=float(mult[2]),
                                           source=f"reference run {path}")


def load_reference_runs(folder: str | Path | None = None) -> list[ReferenceRun]:
    """Every ``*.npz`` of `folder` (default `REFERENCE_DIR`), sorted by name."""
    folder = Path(folder) if folder else REFERENCE_DIR
    files = sorted(folder.glob("*.npz"))
    if not files:
        raise TryonError(f"--reference {folder}: no ARCSim runs (*.npz) found")
    runs = []
    for path in files:
        obs = load_observed(path)
        if not obs.dt_given:
            raise InputFileError(f"reference run {path}: 'dt' (the reference simulator's time step) is required")
        runs.append(ReferenceRun(path.stem, obs, true_fabric(path)))
    return runs


def variant_model(run: ReferenceRun, without: str | None) -> ClothModel:
    """ARCSim's scene, or with one of `CAUSES` replaced by tryon's default: the pinned
    vertices held exactly (no soft handles) and/or the wind's Jacobian in the solve."""
    hard = without in ("soft handles", CAUSES[2])
    obs = dataclasses.replace(run.obs, handle_stiffness=0.0) if hard else run.obs
    model = obs.model(run.fabric)
    if without in ("explicit wind", CAUSES[2]):
        model.wind = dataclasses.replace(model.wind, implicit=True)
    return model


def error_per_frame(x: np.ndarray, reference: np.ndarray, size: float) -> np.ndarray:
    """Mean vertex distance per frame over the cloth size (frame 0 included, 0 there)."""
    return np.linalg.norm(x - reference, axis=-1).mean(axis=1) / size


def _record(run: ReferenceRun, role: str, dt: float, x: np.ndarray, wall_s: float, **extra) -> dict:
    per_frame = error_per_frame(x, run.obs.positions, run.obs.cloth_size())
    return {"reference": f"{run.name}.npz", "material": run.fabric.name, "reference_dt": run.obs.dt, "role": role,
            "dt": dt, "error": float(per_frame[1:].mean()), "error_last_frame": float(per_frame[-1]),
            "error_per_frame": per_frame.tolist(), "wall_s": wall_s, **extra}


def _simulate(run: ReferenceRun, dt: float, without: str | None = None) -> tuple[np.ndarray, float]:
    obs = run.obs
    spf = max(1, int(round(obs.frame_time / dt)))
    tic = time.perf_counter()
    x = simulate_frames(variant_model(run, without), obs.num_frames, spf, obs.frame_time / spf)
    return x, time.perf_counter() - tic


def run_records(run: ReferenceRun, dts=DTS) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Every record of one reference run (module docstring) and the frames of the pictures."""
    own = run.obs.dt
    x_own, wall = _simulate(run, own)
    records = [_record(run, "own", own, x_own, wall)]
    for cause in CAUSES:
        x, wall = _simulate(run, own, cause)
        records.append(_record(run, "cause", own, x, wall, without=cause))
    for dt in dts:
        if not np.isclose(dt, own):
            x, wall = _simulate(run, dt)
            records.append(_record(run, "dt", dt, x, wall))
    tic = time.perf_counter()
    setup = prepare_fit(camera_only(run.obs))  # what fit-fabric decides from the frames alone
    check_s = time.perf_counter() - tic
    x_fit, wall = _simulate(run, setup.dt)
    records.append(_record(run, "fit-fabric", setup.dt, x_fit, wall, choice=setup.report["time_step"],
                           choice_wall_s=check_s))
    return records, {"own": x_own, "fit-fabric": x_fit}


def reference_records(runs: list[ReferenceRun]) -> list[dict]:
    """ARCSim against itself: each run against the same fabric's run at another step."""
    out = []
    for run in runs:
        for other in runs:
            if other is run or other.fabric.name != run.fabric.name or np.isclose(other.obs.dt, run.obs.dt):
                continue
            if other.obs.positions.shape != run.obs.positions.shape:
                continue
            out.append(_record(run, "reference", other.obs.dt, other.obs.positions, 0.0, compared_with=f"{other.name}.npz"))
    return out


def summarise(records: list[dict]) -> dict:
    """Worst error at the runs' own steps, and each cause's share (error added when removed)."""
    own = {r["reference"]: r["error"] for r in records if r["role"] == "own"}
    shares = {}
    for cause in CAUSES:
        added = [r["error"] - own[r["reference"]] for r in records if r.get("without") == cause]
        shares[cause] = {"mean_error_added": float(np.mean(added)), "max_error_added": float(np.max(added))}
    fit = [r["error"] for r in records if r["role"] == "fit-fabric"]
    arcsim = [r["error"] for r in records if r["role"] == "reference"]
    return {"role": "summary", "runs": len(own), "max_error_own_dt": max(own.values()),
            "mean_error_own_dt": float(np.mean(list(own.values()))), "within_1_percent": max(own.values()) <= 0.01,
            "cause_shares": shares, "max_error_fit_fabric_dt": max(fit) if fit else None,
            "arcsim_dt_bias": [min(arcsim), max(arcsim)] if arcsim else None}


def _error_plot(path: Path, run_name: str, records: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    for r in records:
        label = {"own": f"tryon, dt {r['dt']:g} (the run's own)", "fit-fabric": f"tryon, dt {r['dt']:g} (fit-fabric's)",
                 "cause": f"dt {r['dt']:g} without {r.get('without')}", "dt": f"tryon, dt {r['dt']:g}",
                 "reference": f"ARCSim, dt {r['dt']:g}"}[r["role"]]
        style = {"own": "-", "fit-fabric": "-", "cause": ":", "dt": "--", "reference": "-."}[r["role"]]
        ax.plot(100 * np.asarray(r["error_per_frame"]), style, lw=2.0 if r["role"] == "own" else 1.2,
                label=f"{label}: {100 * r['error']:.2f} %")
    ax.set_xlabel("frame (0.04 s)")
    ax.set_ylabel("distance to ARCSim / cloth size (%)")
    ax.set_title(f"{run_name}: tryon against ARCSim 0.3.1")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def _frames_picture(path: Path, run: ReferenceRun, frames: dict[str, np.ndarray]) -> None:
    from tryon.render.sim_pictures import sequences_png

    sequences_png(path, run.obs.faces, [run.obs.positions, frames["own"], frames["fit-fabric"]])


def _print_table(records: list[dict]) -> None:
    print(f"{'reference':34s} {'role':10s} {'dt':>7s} {'error %':>8s}  note")
    for r in records:
        if r["role"] == "summary":
            continue
        note = r.get("without") and f"without {r['without']}" or r.get("compared_with", "")
        print(f"{r['reference']:34s} {r['role']:10s} {r['dt']:7.4f} {100 * r['error']:8.2f}  {note}")


def run_fidelity_bench(json_path: str, reference: str | None = None, pictures: bool = True) -> list[dict]:
    """Run the benchmark (module docstring), print a table and write the records as JSON."""
    with one_torch_thread():
        return _run(json_path, reference, pictures)


def _run(json_path: str, reference: str | None, pictures: bool) -> list[dict]:
    runs = load_reference_runs(reference)
    records: list[dict] = []
    out = Path(json_path)
    for run in runs:
        rows, frames = run_records(run)
        records += rows
        if pictures:
            _error_plot(out.with_name(f"{out.stem}-{run.name}.png"), run.name, rows)
            _frames_picture(out.with_name(f"{out.stem}-{run.name}-frames.png"), run, frames)
    records += reference_records(runs)
    records.append(summarise(records))
    _print_table(records)
    write_records(json_path, records)
    return records
