"""The `hanging` cloth run in NVIDIA Newton, in this process, as a peer for `tryon bench sim`.

Newton (https://github.com/newton-physics/newton) is optional: install it with
``pip install newton==1.8.0 warp-lang==1.19.0``. When it is importable the bench runs the
same cloth with Newton's Style3D solver (projective dynamics, Baraff-Witkin anisotropic
stretch, Bergou 2006 quadratic bending, self-collision on) or VBD solver (vertex block
descent, neo-Hookean membrane, dihedral-angle bending) and prints tryon's speed ratio.

Scene, as tryon's `hanging` example: a 1 m square of ``grid x grid`` vertices lying flat at
z = 1.5 m, x, y in [-0.5, 0.5], the same alternating-diagonal triangulation, pinned at its
two corners with maximum y, gravity (0, 0, -9.8). Wind is not modelled in Newton. One frame
is 0.01 s of simulated time: Style3D takes 2 substeps x 10 nonlinear iterations x 10 PCG
iterations, VBD 10 substeps x 10 iterations, as in the shared Newton anchor measurements.

Material: gray-interlock (Wang 2011, as stored by ARCSim 0.3.1), 0.187 kg/m^2, with constant
stiffnesses: Newton's cloth models are not strain-dependent. Wang's piecewise-linear model is
sampled at a strain of 2 %, the bulk strain of this scene (1 m of 0.187 kg/m^2 cloth under
gravity pulls the top row with about 1.8 N/m): per term, ``k = 2 (c_0 + s (c_dir - c_0))``
with ``s = 6 x 0.02`` as in ARCSim's ``evaluate_stretching_sample``, c_0 the zero-strain row
and c_dir the 1/6-strain row of the direction that term measures (0 deg for k0, 90 deg for k2,
45 deg for k3, and 90 deg, the hanging cloth's dominant stretch, for the coupling k1), each
clamped at 0. ARCSim's stretch energy ``A/2 (k0 Guu^2 + 2 k1 Guu Gvv + k2 Gvv^2 + 2 k3 Guv^2)``
maps to Style3D's
``A/2 (ku (|Fu|-1)^2 + kv (|Fv|-1)^2 + ks (Fu.Fv)^2)`` as ku = k0, kv = k2, ks = k3 / 2
(small strain: Guu ~ |Fu| - 1, Guv = Fu.Fv / 2). ARCSim's hinge energy
``ke l^2 theta^2 / (8 (A0 + A1))`` equals Bergou's ``k/2 x^T Q x`` with
``Q = 3 / (A0 + A1) w w^T`` when k = ke / 12 (checked numerically on a folded hinge).
For VBD (isotropic; small-strain energy ``mu G:G + lambda/2 tr(G)^2``) the fit is
lambda = k1 (the coupling, clamped to 0 for gray-interlock at 2 %) and mu = (k0 + k2 + k3) / 6, the mean of the
values k0 / 2, k2 / 2, k3 / 2 that match the u, v and shear terms one at a time; the dihedral
bending stiffness per rest length is ke / (4 h) for an axis-aligned edge of a grid with
spacing h (same energy as ARCSim's for that edge), ke averaged over the three directions.
"""

from __future__ import annotations

import contextlib
import functools
import io
import time
from typing import Any

import numpy as np

from tryon.errors import SceneError, TryonError

INSTALL_HINT = "pip install newton==1.8.0 warp-lang==1.19.0"
FRAME_DT = 0.01
GRAVITY = -9.8
HEIGHT = 1.5
SOLVERS = {
    # name: (substeps per 0.01 s frame, nonlinear iterations, linear (PCG) iterations)
    "style3d": (2, 10, 10),
    "vbd": (10, 10, 0),
}

# gray-interlock, Wang 2011 / ARCSim 0.3.1 materials/gray-interlock.json
GRAY_INTERLOCK_DENSITY = 0.187  # kg/m^2
OPERATING_STRAIN = 0.02
# rows of the 6 x 4 stretching table (c0..c3, N/m; ARCSim doubles them): zero strain, and 1/6
# strain with the dominant stretch at 0, 45 and 90 degrees from u
_STRETCH_ROWS = {
    "zero": (16.593832, -14.69599, 34.477123, 36.860302),
    "0deg": (46.364765, 53.694656, 261.013855, -29.691301),
    "45deg": (123.98922, 105.18177, 365.966217, 44.217571),
    "90deg": (127.44381, 85.848587, 405.872833, 32.238411),
}
_TERM_DIRECTION = ("0deg", "90deg", "90deg", "45deg")  # which sample row governs k0, k1, k2, k3
_BEND_COL0 = (2.3191698e-05, 2.4749964e-05, 1.4267624e-05)  # N m; hinge parallel to u, diagonal, parallel to v


def newton_available() -> bool:
    """True when the optional `newton` and `warp` packages can be imported."""
    return _import_newton() is not None


@functools.lru_cache(maxsize=1)
def _import_newton() -> tuple[Any, Any] | None:
    try:
        import warp as wp

        wp.config.log_level = getattr(wp, "LOG_WARNING", 30)  # no per-module load lines in the bench output
        import newton
    except (ImportError, OSError):
        return None
    return newton, wp


def wang_stiffness_at(strain: float) -> tuple[float, float, float, float]:
    """ARCSim's gray-interlock (k0, k1, k2, k3) in N/m at a principal strain `strain`, each term
    taken in the direction it measures (see the module docstring)."""
    s = min(max(6.0 * strain, 0.0), 1.0)
    zero = _STRETCH_ROWS["zero"]
    return tuple(
        2.0 * max(zero[i] + s * (_STRETCH_ROWS[d][i] - zero[i]), 0.0) for i, d in enumerate(_TERM_DIRECTION)
    )


def gray_interlock_newton_params(grid: int) -> dict[str, Any]:
    """Newton material parameters for gray-interlock (derivation in the module docstring)."""
    k0, k1, k2, k3 = wang_stiffness_at(OPERATING_STRAIN)
    b_u, b_diag, b_v = _BEND_COL0
    h = 1.0 / (grid - 1)
    return {
        "density_kg_m2": GRAY_INTERLOCK_DENSITY,
        "operating_strain": OPERATING_STRAIN,
        # Style3D: (weft u, warp v, shear) N/m; bending (edge parallel to v, parallel to u, diagonal) N m
        "style3d_tri_aniso_ke": (k0, k2, 0.5 * k3),
        "style3d_edge_aniso_ke": (b_v / 12.0, b_u / 12.0, b_diag / 12.0),
        # VBD: Lame parameters (N/m) of the neo-Hookean membrane; bending stiffness per rest length
        "vbd_tri_ke": (k0 + k2 + k3) / 6.0,
        "vbd_tri_ka": k1,
        "vbd_edge_ke": float(np.mean(_BEND_COL0)) / (4.0 * h),
    }


def hanging_grid(grid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """Positions [N,3], material coordinates [N,2], faces [F,3] and the two pinned vertices.

    The same layout as `tryon.sim.mesh.grid_mesh((grid, grid), (1, 1), (-0.5, -0.5, 1.5))`:
    u along x, v along y, alternating diagonals; pins are the 'top-left'/'top-right' corners.
    """
    n = grid
    s = np.linspace(0.0, 1.0, n)
    uu, vv = np.meshgrid(s, s, indexing="xy")
    uv = np.stack([uu.ravel(), vv.ravel()], 1)
    x = np.column_stack([uv[:, 0] - 0.5, uv[:, 1] - 0.5, np.full(n * n, HEIGHT)])
    idx = np.arange(n * n).reshape(n, n)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    ii, jj = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="xy")
    flip = ((ii + jj) % 2 == 1).ravel()[:, None]
    f1 = np.where(flip, np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    f2 = np.where(flip, np.stack([b, d, c], 1), np.stack([a, d, c], 1))
    return x, uv, np.concatenate([f1, f2]), [(n - 1) * n, n * n - 1]


def _check_args(grid: int, frames: int, solver: str) -> None:
    if not isinstance(grid, int) or grid < 2:
        raise SceneError(f"newton reference: grid must be an integer >= 2 (vertices per side), got {grid!r}")
    if not isinstance(frames, int) or frames < 1:
        raise SceneError(f"newton reference: frames must be an integer >= 1, got {frames!r}")
    if solver not in SOLVERS:
        raise SceneError(f"newton reference: unknown solver {solver!r}; choose one of {sorted(SOLVERS)}")


def _build_model(newton: Any, wp: Any, grid: int, solver: str, params: dict[str, Any]) -> Any:
    """Newton Model of the hanging cloth; pinned vertices are inactive with zero mass."""
    x, uv, faces, pins = hanging_grid(grid)
    builder = newton.ModelBuilder(up_axis=newton.Axis.Z, gravity=(0.0, 0.0, GRAVITY))
    common = {
        "pos": wp.vec3(0.0, 0.0, 0.0),
        "rot": wp.quat_identity(),
        "vel": wp.vec3(0.0, 0.0, 0.0),
        "vertices": [wp.vec3(*p) for p in x.tolist()],
        "indices": faces.ravel().tolist(),
        "density": params["density_kg_m2"],
        "scale": 1.0,
        "particle_radius": 5.0e-3,
    }
    if solver == "style3d":
        from newton.solvers import style3d

        newton.solvers.SolverStyle3D.register_custom_attributes(builder)
        style3d.add_cloth_mesh(
            builder,
            panel_verts=[wp.vec2(*p) for p in uv.tolist()],
            panel_indices=faces.ravel().tolist(),
            tri_aniso_ke=wp.vec3(*params["style3d_tri_aniso_ke"]),
            edge_aniso_ke=wp.vec3(*params["style3d_edge_aniso_ke"]),
            **common,
        )
    else:
        builder.add_cloth_mesh(
            tri_ke=params["vbd_tri_ke"], tri_ka=params["vbd_tri_ka"], edge_ke=params["vbd_edge_ke"], **common
        )
    for i in pins:
        builder.particle_flags[i] = builder.particle_flags[i] & ~newton.ParticleFlags.ACTIVE
        builder.particle_mass[i] = 0.0
    if solver == "vbd":
        builder.color(include_bending=True)
    return builder.finalize()


def _make_solver(newton: Any, model: Any, solver: str) -> Any:
    _, iters, linear = SOLVERS[solver]
    if solver == "style3d":
        cfg = newton.solvers.SolverStyle3D.Config(iterations=iters, linear_iterations=linear)
        return newton.solvers.SolverStyle3D(model=model, config=cfg)  # self-collision is on by default
    return newton.solvers.SolverVBD(model=model, iterations=iters, particle_enable_self_contact=False)


class _Runner:
    """Model, solver, states and contacts; `frame()` advances 0.01 s of simulated time."""

    def __init__(self, newton: Any, model: Any, solver: str) -> None:
        self.model = model
        self.solver = _make_solver(newton, model, solver)
        self.substeps = SOLVERS[solver][0]
        self.state0, self.state1 = model.state(), model.state()
        self.control = model.control()
        self.pipeline = newton.CollisionPipeline(model)
        self.contacts = self.pipeline.contacts()

    def frame(self) -> None:
        dt = FRAME_DT / self.substeps
        for _ in range(self.substeps):
            self.state0.clear_forces()
            self.pipeline.collide(self.state0, self.contacts)
            self.solver.step(self.state0, self.state1, self.control, self.contacts, dt)
            self.state0, self.state1 = self.state1, self.state0

    def positions(self) -> np.ndarray:
        return self.state0.particle_q.numpy().astype(np.float64)


def max_edge_stretch(x: np.ndarray, x_rest: np.ndarray, faces: np.ndarray) -> float:
    """Largest ratio current / rest length over the mesh edges (1.0 = unstretched)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    cur = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1)
    rest = np.linalg.norm(x_rest[e[:, 0]] - x_rest[e[:, 1]], axis=1)
    return float(np.max(cur / rest))


def run_newton_hanging(grid: int, frames: int, solver: str = "style3d", device: str = "cpu") -> dict:
    """Time `frames` frames (0.01 s each) of the hanging cloth in Newton on `device`.

    Model building, solver set-up and one warm-up frame (where Warp compiles or loads its
    kernels) are reported as `compile_s` and kept out of the timing. Raises `TryonError`
    when Newton is not installed and `SceneError` on bad arguments.
    """
    _check_args(grid, frames, solver)
    mods = _import_newton()
    if mods is None:
        raise TryonError(
            f"the Newton comparison needs the optional packages newton and warp-lang: {INSTALL_HINT} "
            f"(or run the bench without the Newton comparison)"
        )
    newton, wp = mods
    try:
        dev = wp.get_device(device)
    except Exception as exc:  # warp raises plain RuntimeError/ValueError for unknown devices
        raise SceneError(f"newton reference: device {device!r} is not available to Warp ({exc}); use 'cpu'") from exc
    params = gray_interlock_newton_params(grid)
    x_rest, _, faces, _ = hanging_grid(grid)
    t0 = time.perf_counter()
    with wp.ScopedDevice(dev), contextlib.redirect_stdout(io.StringIO()):  # Newton's set-up timers print
        runner = _Runner(newton, _build_model(newton, wp, grid, solver, params), solver)
        runner.frame()
        wp.synchronize_device(dev)
    compile_s = time.perf_counter() - t0
    per_frame = []
    with wp.ScopedDevice(dev):
        for _ in range(frames):
            t = time.perf_counter()
            runner.frame()
            wp.synchronize_device(dev)
            per_frame.append(time.perf_counter() - t)
    x = runner.positions()
    substeps, iters, linear = SOLVERS[solver]
    return {
        "solver": solver,
        "grid": grid,
        "vertices": grid * grid,
        "frames": frames,
        "s_per_frame": float(np.mean(per_frame)),
        "s_per_frame_median": float(np.median(per_frame)),
        "compile_s": compile_s,
        "max_stretch": max_edge_stretch(x, x_rest, faces),
        "finite": bool(np.isfinite(x).all()),
        "sim_time": round(FRAME_DT * (frames + 1), 6),
        "z_min": float(x[:, 2].min()),
        "com": [round(float(v), 4) for v in x.mean(axis=0)],
        "newton_version": str(newton.__version__),
        "warp_version": str(wp.config.version),
        "device": str(dev),
        "frame_dt": FRAME_DT,
        "substeps": substeps,
        "iterations": iters,
        "linear_iterations": linear,
        "self_collision": solver == "style3d",
        "wind": False,
        "material": {"fabric": "gray-interlock (linearised at zero strain)", **params},
    }
