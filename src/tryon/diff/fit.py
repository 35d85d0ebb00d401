"""Fabric estimation from observed motion (`tryon fit-fabric`).

The unknowns are log-multipliers ``theta`` of groups of the Wang 2011 parameter vector,
starting from the element-wise mean of the 10 measured presets (`mean_preset_fabric`):

    density | linear stretching k0, k1, k2, k3 (row 0 of the 6x4 data) |
    non-linear stretching (rows 1-5) | bending rows 0, 1, 2 (edge along u, diagonal, v)

so ``p = p_mean * exp(G theta)`` stays positive and the shape of the measured tables is
kept. The loss is the mean squared vertex distance to the observed frames, over the cloth
size squared, plus a small pull of ``theta`` to 0 (it only decides parameters the motion
does not show).

Methods (`--method`):

* ``gradient``: L-BFGS-B on gradients from the differentiable simulator, over
  progressively more frames (a quarter, half, then all of the sequence);
* ``finite-difference``: the same optimiser and schedule with forward-difference
  gradients (1 + K simulations per gradient);
* ``physical``: no optimisation: density from Newton's law on the first frames (wind
  force against observed acceleration minus gravity), linear stretching from the largest
  mean edge stretch of the hanging cloth under its weight.
"""

from __future__ import annotations

from collections.abc import Callable

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import minimize
from tqdm import tqdm

from tryon.diff.identify import forward_jacobian, identifiability, residual
from tryon.diff.momentum import PIN_DRIFT_MIN, frame_kinematics, momentum_estimate, pin_drift
from tryon.diff.observed import Observation, load_observed, simulate_frames
from tryon.diff.timestep import choose_dt
from tryon.diff.rollout import DiffSimulator
from tryon.errors import SimulationError, TryonError
from tryon.fabric.presets import load_fabric, mean_preset_fabric, save_fabric
from tryon.fabric.wang2011 import WangFabric
from tryon.io.atomic import atomic_output_dir, atomic_path, atomic_write, check_output_dir
from tryon.io.json_safe import dumps_json
from tryon.sim.model import ClothModel
from tryon.sim.scene import load_scene

METHODS = ("gauss-newton", "gradient", "finite-difference", "physical")
GROUP_NAMES = ("density", "stretch_k0", "stretch_k1", "stretch_k2", "stretch_k3", "stretch_nonlinear",
               "bend_u", "bend_diagonal", "bend_v")
BOUND = 3.0  # |theta| <= 3: each group within a factor e^3 = 20 of the mean fabric
PRIOR = 1e-6  # weight of |theta|^2 (the loss is ~1e-4 at a 1 % simulation error)
FD_STEP = 1e-4
STAGE_ITERATIONS = (8, 8, 8)
STAGE_EVALUATIONS = (14, 12, 10)  # simulations per stage at most (line searches included)
GN_ITERATIONS = (4, 3, 3)  # Gauss-Newton iterations per stage
GN_FD_STEP = 1e-2  # log-multiplier step of the Jacobian's forward differences (a 1 % change)
GN_DAMPING = 1e-2  # Levenberg-Marquardt damping at the start of a stage (relative to diag(J^T J))
# trial steps per iteration, the damping raised 4x after each that fails (up to 4^7 = 1.6e4x):
# the late frames flap chaotically, so the loss over them is rough and often only a short step
# descends (with 4 trials the last stages of a fit often ended at their first iteration)
GN_RETRIES = 8


def parameter_groups() -> torch.Tensor:
    """0/1 matrix ``[40, 9]`` mapping the groups (module docstring) to Wang parameters."""
    G = torch.zeros(40, len(GROUP_NAMES), dtype=torch.float64)
    G[0, 0] = 1.0
    for c in range(4):
        G[1 + c, 1 + c] = 1.0
    G[5:25, 5] = 1.0
    for r in range(3):
        G[25 + 5 * r:30 + 5 * r, 6 + r] = 1.0
    return G


@dataclass
class FitResult:
    """Outcome of a fit: the fabric, the loss history and the work done."""

    method: str
    fabric: WangFabric
    theta: np.ndarray
    history: list = field(default_factory=list)
    simulations: int = 0
    simulated_steps: int = 0
    gradient_evaluations: int = 0
    wall_s: float = 0.0
    setup: dict = field(default_factory=dict)  # handles, momentum balance, time step (`prepare_fit`)


class FabricEstimator:
    """Simulates an observation with candidate fabrics and scores them (module docstring)."""

    def __init__(self, obs: Observation, model: ClothModel | None = None, dt: float | None = None,
                 start: WangFabric | None = None, progress: bool = False):
        self.obs = obs
        self.start = start or mean_preset_fabric()
        self.model = model or obs.model(self.start)
        self._sims: dict[float, DiffSimulator] = {}
        self.use_dt(dt or obs.dt)
        self.base = self.start.parameters().detach().clone()
        self.groups = parameter_groups()
        self.x_obs = torch.from_numpy(obs.positions)
        self.size = obs.cloth_size()
        self.simulations = 0
        self.steps = 0
        self.gradients = 0
        self.history: list[dict] = []
        self.progress = progress

    def use_dt(self, dt: float) -> None:
        """Simulate with time step `dt` from now on (coarse-to-fine stages)."""
        self.dt = dt
        self.spf = max(1, int(round(self.obs.frame_time / dt)))
        if dt not in self._sims:
            self._sims[dt] = DiffSimulator(self.model, dt, fabric=self.start)
        self.sim = self._sims[dt]

    def params(self, theta: torch.Tensor) -> torch.Tensor:
        return self.base * torch.exp(self.groups @ theta)

    def fabric(self, theta: np.ndarray, name: str) -> WangFabric:
        fab = self.start.with_parameters(self.params(torch.as_tensor(theta, dtype=torch.float64)).detach())
        fab.name, fab.composition, fab.multipliers = name, "estimated by tryon fit-fabric", {}
        return fab

    def simulate(self, theta: torch.Tensor, frames: int, params: torch.Tensor | None = None) -> torch.Tensor:
        """Simulated positions of frames 0..frames-1 ``[frames, N, 3]`` (of `params`, a
        full parameter vector, when given instead of theta)."""
        steps = (frames - 1) * self.spf
        params = self.params(theta) if params is None else params
        traj = self.sim.rollout(steps, params=params, x0=self.x_obs[0], v0=torch.zeros_like(self.x_obs[0]))
        self.simulations += 1
        self.steps += steps
        return traj.x[:: self.spf]

    def loss(self, theta: torch.Tensor, frames: int) -> torch.Tensor:
        x = self.simulate(theta, frames)
        d2 = ((x[1:] - self.x_obs[1:frames]) ** 2).sum(-1).mean()
        return d2 / self.size**2 + PRIOR * (theta**2).sum()

    def value_and_grad(self, theta: np.ndarray, frames: int, method: str) -> tuple[float, np.ndarray]:
        t = torch.tensor(theta, dtype=torch.float64, requires_grad=method == "gradient")
        if method == "gradient":
            value = self.loss(t, frames)
            (g,) = torch.autograd.grad(value, t)
            self.gradients += 1
            out = float(value.detach()), g.numpy()
        else:
            with torch.no_grad():
                f0 = float(self.loss(t, frames))
                g = np.zeros_like(theta)
                for k in range(len(theta)):
                    step = FD_STEP if theta[k] + FD_STEP <= BOUND else -FD_STEP
                    tk = t.clone()
                    tk[k] += step
                    g[k] = (float(self.loss(tk, frames)) - f0) / step
            out = f0, g
        self.history.append({"frames": frames, "loss": out[0], "simulations": self.simulations, "steps": self.steps})
        return out

    def simulation_error(self, theta: np.ndarray, params: torch.Tensor | None = None) -> tuple[float, np.ndarray]:
        """Mean vertex distance over all frames / cloth size, and the simulated frames (a
        plain forward run, as the Gauss-Newton fit scores candidates)."""
        fabric = self.fabric(theta, "scored") if params is None else self.start.with_parameters(params.detach())
        x = simulate_frames(self.model, self.obs.num_frames, self.spf, self.dt, fabric=fabric)
        err = float(np.linalg.norm(x[1:] - self.obs.positions[1:], axis=-1).mean()) / self.size
        return err, x


def _stages(frames: int) -> list[int]:
    return sorted({max(2, (frames + 3) // 4), max(2, (frames + 1) // 2), frames})


def _schedule(est: FabricEstimator) -> list[tuple[int, float]]:
    """(frames, time step) per stage: a quarter, half, then all of the frames; the early
    stages at twice the fit's step when that still divides a frame."""
    stages = _stages(est.obs.num_frames)
    coarse = est.dt * 2 if est.spf % 2 == 0 else est.dt
    return [(frames, est.dt if k == len(stages) - 1 else coarse) for k, frames in enumerate(stages)]


def fit_by_optimisation(est: FabricEstimator, method: str, frozen: tuple[str, ...] = ()) -> np.ndarray:
    """L-BFGS-B over progressively more frames; returns theta. `frozen` groups stay at
    the start fabric's values."""
    theta = np.zeros(len(GROUP_NAMES))
    bounds = [(0.0, 0.0) if name in frozen else (-BOUND, BOUND) for name in GROUP_NAMES]
    bar = tqdm(desc=f"fit-fabric ({method})", unit="eval", disable=not est.progress, leave=False)
    schedule = _schedule(est)
    for (frames, dt), iters, evals in zip(schedule, STAGE_ITERATIONS[-len(schedule):], STAGE_EVALUATIONS[-len(schedule):]):
        est.use_dt(dt)

        def fun(th: np.ndarray, frames=frames) -> tuple[float, np.ndarray]:
            value, grad = est.value_and_grad(th, frames, method)
            bar.update(1)
            bar.set_postfix(frames=frames, loss=f"{value:.3g}", sims=est.simulations)
            return value, grad

        res = minimize(fun, theta, jac=True, method="L-BFGS-B", bounds=bounds,
                       options={"maxiter": iters, "maxfun": evals, "ftol": 1e-12, "gtol": 1e-10})
        theta = res.x
    bar.close()
    return theta


def fit_by_gauss_newton(est: FabricEstimator, frozen: tuple[str, ...] = ()) -> np.ndarray:
    """Levenberg-Marquardt on the same staged loss as `fit_by_optimisation`: per iteration
    one forward run per free group gives the Jacobian by forward differences, then a
    damped Gauss-Newton step is tried (and the damping raised until the loss drops).
    Forward runs only (no adjoint), and few iterations: Gauss-Newton converges in a
    handful where L-BFGS needs tens of gradients. Returns theta."""
    theta = np.zeros(len(GROUP_NAMES))
    free = [k for k, g in enumerate(GROUP_NAMES) if g not in frozen]
    schedule = _schedule(est)
    bar = tqdm(desc="fit-fabric (gauss-newton)", unit="sim", disable=not est.progress, leave=False)
    for (frames, dt), iters in zip(schedule, GN_ITERATIONS[-len(schedule):]):
        est.use_dt(dt)
        n = (frames - 1) * est.obs.positions.shape[1]

        def cost(r: np.ndarray | None, th: np.ndarray) -> float:
            return float("inf") if r is None else float(r @ r) / n + PRIOR * float(th @ th)

        r = residual(est, theta, frames)
        if r is None:
            raise SimulationError(f"fit-fabric: the start fabric does not simulate at dt {est.dt:g} s")
        current = cost(r, theta)
        mu = GN_DAMPING
        for _ in range(iters):
            J = forward_jacobian(est, theta, r, frames, free, GN_FD_STEP, BOUND, progress=bar)
            A = J.T @ J + n * PRIOR * np.eye(len(free))
            grad = J.T @ r + n * PRIOR * theta[free]
            improved = False
            for _ in range(GN_RETRIES):
                step = np.linalg.solve(A + mu * np.diag(np.diag(A)), -grad)
                trial = theta.copy()
                trial[free] = np.clip(theta[free] + step, -BOUND, BOUND)
                r_trial = residual(est, trial, frames)
                bar.update(1)
                if cost(r_trial, trial) < current:
                    theta, r, current, improved = trial, r_trial, cost(r_trial, trial), True
                    mu = max(mu / 3.0, 1e-6)
                    break
                mu *= 4.0
            est.history.append({"frames": frames, "loss": current, "simulations": est.simulations, "steps": est.steps})
            bar.set_postfix(frames=frames, loss=f"{current:.3g}", sims=est.simulations)
            if not improved:
                break
    bar.close()
    return theta


def physical_estimate(est: FabricEstimator) -> np.ndarray:
    """Density from Newton's law, linear stretching from the largest mean edge stretch."""
    obs, m = est.obs, est.model
    free = np.ones(m.num_vertices, dtype=bool)
    free[obs.pinned] = False
    k = min(4, obs.num_frames - 2)
    num = den = 0.0
    area = m.vertex_area.numpy()
    for _, _, acc, fw in frame_kinematics(obs, m, range(1, k + 1)):  # the first frames
        r = acc - obs.gravity
        num += float((fw[free] * r[free]).sum())
        den += float((area[free, None] * r[free] ** 2).sum())
    density = num / den if den > 0 and num > 0 else float(est.start.density)
    theta = np.zeros(len(GROUP_NAMES))
    theta[0] = np.clip(np.log(density / float(est.start.density)), -BOUND, BOUND)
    # largest stretch: the hanging cloth's weight per unit width, rho g L, is carried by
    # the material above; at the frame of largest mean edge strain, k = rho g L / (2 strain)
    edges = m.edges.numpy()
    rest = np.linalg.norm(obs.uv[edges[:, 0]] - obs.uv[edges[:, 1]], axis=1)
    lengths = np.linalg.norm(obs.positions[:, edges[:, 0]] - obs.positions[:, edges[:, 1]], axis=2)
    strain = max(float((lengths / rest - 1.0).mean(1).max()), 1e-4)
    length = float(obs.uv[:, 1].max() - obs.uv[:, 1].min())
    k_est = density * float(np.linalg.norm(obs.gravity)) * length / (2.0 * strain)
    k_mean = 2.0 * float(est.start.stretching_data[0, [0, 2]].mean())
    theta[1:5] = np.clip(np.log(k_est / k_mean), -BOUND, BOUND)
    return theta


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm())


def parameter_errors(fit: WangFabric, truth: WangFabric) -> dict:
    """Relative Frobenius errors of the fitted data against the truth (fractions)."""
    return {
        "density_error": abs(float(fit.density) - float(truth.density)) / float(truth.density),
        "stretching_error": _rel(fit.stretching_data, truth.stretching_data),
        "linear_stretching_error": _rel(fit.stretching_data[0], truth.stretching_data[0]),
        "nonlinear_stretching_error": _rel(fit.stretching_data[1:], truth.stretching_data[1:]),
        "bending_error": _rel(fit.bending_data, truth.bending_data),
    }


@dataclass
class FitSetup:
    """What `prepare_fit` decided before optimising: the observation as modelled (soft
    handles or exact pins), the start fabric, the time step and the frozen groups."""

    obs: Observation
    start: WangFabric
    dt: float
    frozen: tuple[str, ...] = ()
    report: dict = field(default_factory=dict)


def prepare_fit(obs: Observation, dt: float | None = None, progress: bool = False) -> FitSetup:
    """For a hanging-in-wind observation: handles, density and time step before the fit.

    1. Pinned vertices that drift hang from soft handles; without a ``handle_stiffness``
       in the file, the momentum balance (`tryon.diff.momentum`) estimates it.
    2. The same balance gives the density, independent of any elastic model; the fit
       keeps it (the density group is frozen) instead of trading it against motion the
       elastic model cannot explain.
    3. Without a ``dt`` in the file (or `dt`), the step comes from the convergence check
       (`tryon.diff.timestep.choose_dt`) with the start fabric.
    """
    start = mean_preset_fabric()
    report: dict = {}
    frozen: tuple[str, ...] = ()
    balance = momentum_estimate(obs, obs.model(start))
    if balance is None and pin_drift(obs) >= PIN_DRIFT_MIN:
        report["momentum_balance"] = {"failed": "the pinned vertices drift, but the balance gave no positive density "
                                                "and stiffness; fitting with the pins held exactly"}
    if balance is not None:
        report["momentum_balance"] = balance.as_dict()
        if obs.handle_stiffness <= 0:
            obs = dataclasses.replace(obs, handle_stiffness=balance.handle_stiffness)
            report["handles"] = "soft, stiffness from the momentum balance"
        p = start.parameters().detach().clone()
        p[0] = balance.density
        start = start.with_parameters(p)
        start.name = "wang2011-mean, density from the momentum balance"
        frozen = ("density",)
    report.setdefault("handles", "soft, stiffness from the file" if obs.handle_stiffness > 0 else "held exactly")
    report["handle_stiffness"] = obs.handle_stiffness
    if dt is None and not obs.dt_given:
        if progress:
            print("fit-fabric: choosing the time step (convergence check)")
        choice = choose_dt(obs, start)
        dt = choice.dt
        report["time_step"] = choice.as_dict()
    else:
        dt = dt or obs.dt
        report["time_step"] = {"dt": dt, "source": "the observation's dt" if obs.dt_given else "given"}
    report["frozen_groups"] = list(frozen)
    return FitSetup(obs, start, dt, frozen, report)


def fit_fabric(obs: Observation, method: str = "gauss-newton", model: ClothModel | None = None, dt: float | None = None,
               name: str = "fitted", progress: bool = False) -> tuple[FitResult, FabricEstimator]:
    """Estimate a fabric for `obs` (Python API of `tryon fit-fabric`). Without `model`
    (the hanging-in-wind scene) `prepare_fit` sets up handles, density and time step."""
    if method not in METHODS:
        raise TryonError(f"unknown fit method {method!r}; choose one of {', '.join(METHODS)}")
    tic = time.perf_counter()
    setup = FitSetup(obs, mean_preset_fabric(), dt or obs.dt) if model is not None else prepare_fit(obs, dt, progress)
    est = FabricEstimator(setup.obs, model=model, dt=setup.dt, start=setup.start, progress=progress)
    if method == "physical":
        theta = physical_estimate(est)
    elif method == "gauss-newton":
        theta = fit_by_gauss_newton(est, setup.frozen)
    else:
        theta = fit_by_optimisation(est, method, setup.frozen)
    theta[[GROUP_NAMES.index(g) for g in setup.frozen]] = 0.0
    result = FitResult(method, est.fabric(theta, name), theta, est.history, est.simulations, est.steps,
                       est.gradients, time.perf_counter() - tic, setup.report)
    return result, est


# --------------------------------------------------------------------------- outputs


def _loss_plot(path: Path, history: list[dict], method: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    if history:
        sims = [h["simulations"] for h in history]
        ax.semilogy(sims, [h["loss"] for h in history], ".-", label=method)
        for frames in sorted({h["frames"] for h in history}):
            first = next(h for h in history if h["frames"] == frames)
            ax.axvline(first["simulations"], color="0.8", lw=0.8)
            ax.text(first["simulations"], first["loss"], f" {frames} frames", fontsize=7, va="bottom")
    ax.set_xlabel("simulations")
    ax.set_ylabel("loss (mean squared distance / size^2)")
    ax.set_title(f"fit-fabric: {method}")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def run_fit_fabric(observed: str, out: str, scene: str | None = None, truth: str | None = None,
                   method: str = "gauss-newton", progress: bool = True, force: bool = False,
                   comparison_picture: Callable[[Path, np.ndarray, np.ndarray, np.ndarray], None] | None = None) -> dict:
    """`tryon fit-fabric`: fit, then write fabric.json, loss_curve.png, observed_vs_fit.png
    and report.json into `out` (atomically, as one folder). Returns the report."""
    check_output_dir(out, force=force)
    obs = load_observed(observed)
    truth_fabric = load_fabric(truth) if truth else None
    if truth_fabric is not None and not isinstance(truth_fabric, WangFabric):
        raise TryonError(f"--truth {truth!r}: errors are defined for Wang 2011 fabrics; give a measured preset")
    model, dt = None, None
    if scene:
        sc = load_scene(scene)
        if sc.model.num_vertices != obs.positions.shape[1]:
            raise TryonError(f"--scene {scene}: its cloth has {sc.model.num_vertices} vertices, the observation "
                             f"{obs.positions.shape[1]}; use the scene the sequence was recorded in")
        model, dt = sc.model, sc.dt
    name = f"fit-{obs.fabric or Path(observed).stem}"
    result, est = fit_fabric(obs, method, model=model, dt=dt, name=name, progress=progress)
    start_error, _ = est.simulation_error(np.zeros(len(GROUP_NAMES)))
    sim_error, frames = est.simulation_error(result.theta)
    report = {
        "method": method, "observed": str(observed), "frames": obs.num_frames, "vertices": int(obs.positions.shape[1]),
        "simulation_error": sim_error, "start_simulation_error": start_error,
        "simulations": result.simulations, "simulated_steps": result.simulated_steps,
        "gradient_evaluations": result.gradient_evaluations, "wall_s": result.wall_s,
        "final_loss": result.history[-1]["loss"] if result.history else None,
        "theta": dict(zip(GROUP_NAMES, map(float, result.theta))),
        "fitted": {"name": name, "density_kg_m2": float(result.fabric.density)},
        "note": "simulations, simulated_steps and wall_s count the fit only; two more runs score the start and the result",
    }
    report.update(result.setup)
    report["dt"] = est.dt
    if method != "physical":
        tic = time.perf_counter()
        free = [k for k, g in enumerate(GROUP_NAMES) if g not in result.setup.get("frozen_groups", [])]
        report["identifiability"] = identifiability(est, result.theta, GROUP_NAMES, free)
        report["identifiability"]["wall_s"] = time.perf_counter() - tic
    if truth_fabric is not None:
        report["truth"] = truth_fabric.name
        report.update(parameter_errors(result.fabric, truth_fabric))
        report["start_errors"] = parameter_errors(est.start, truth_fabric)
        report["simulation_error_at_truth"], _ = est.simulation_error(result.theta, truth_fabric.parameters().detach())
    with atomic_output_dir(out, force=force) as tmp:
        save_fabric(result.fabric, tmp / "fabric.json")
        _loss_plot(tmp / "loss_curve.png", result.history, method)
        if comparison_picture is not None:  # e.g. tryon.render.sim_pictures.sequence_comparison_png
            comparison_picture(tmp / "observed_vs_fit.png", obs.faces, obs.positions, frames)
        with atomic_write(tmp / "report.json") as fh:
            fh.write(dumps_json(report, indent=2))
    return report
