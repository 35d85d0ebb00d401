"""ARCSim's hanging-in-wind scene: soft node handles, explicit wind, the time-step check,
and `tryon bench fidelity` against the ARCSim runs shipped in the package."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from tryon.bench.fidelity import REFERENCE_DIR, load_reference_runs, run_fidelity_bench, variant_model
from tryon.diff import DiffSimulator
from tryon.diff.observed import load_observed, make_observed, save_observed, simulate_frames
from tryon.diff.timestep import DT_TOLERANCE, choose_dt
from tryon.errors import SceneError
from tryon.fabric.presets import load_fabric
from tryon.sim.integrator import ImplicitEulerSolver
from tryon.sim.model import ClothState, SoftHandle
from tryon.sim.scene import example_scene

F64 = torch.float64
K_HANDLE = 1.0e3  # N/m, ARCSim's handle stiffness in the reference scene


def _soft_observation(resolution: int = 5, duration: float = 0.24, dt: float = 0.01):
    """A tryon-made hanging-in-wind observation whose corners hang from soft handles."""
    obs = make_observed("gray-interlock", resolution=resolution, duration=duration, dt=dt)
    obs.handle_stiffness = K_HANDLE
    obs.positions = simulate_frames(obs.model(load_fabric("gray-interlock")), obs.num_frames, obs.steps_per_frame, dt)
    return obs


def _system(model, x, v, dt=0.01, t=0.0):
    solver = ImplicitEulerSolver(model)
    state = ClothState(torch.from_numpy(x), torch.from_numpy(v), t)
    return solver, solver.assemble(state, dt, None, None, np.zeros((0, 3)), np.zeros((0, 3)))


def test_soft_handle_adds_an_implicit_spring_to_its_start_position():
    obs = _soft_observation()
    soft = obs.model(load_fabric("gray-interlock"))
    assert len(soft.pinned) == 0 and len(soft.handles) == 1
    obs.handle_stiffness = 0.0
    hard = obs.model(load_fabric("gray-interlock"))
    x, v = obs.positions[3].copy(), np.random.default_rng(0).normal(0, 0.1, obs.positions[3].shape)
    solver, with_handles = _system(soft, x, v)
    _, without = _system(hard.__class__(hard.mesh, hard.fabric, gravity=tuple(hard.gravity.tolist()), wind=hard.wind),
                         x, v)
    idx = obs.pinned
    drift = x[idx] - obs.positions[0][idx]
    assert np.abs(drift).max() > 1e-5
    np.testing.assert_allclose(with_handles.f[idx] - without.f[idx], -K_HANDLE * drift, rtol=1e-9, atol=1e-12)
    diag = solver.pattern.diag_block[idx]
    np.testing.assert_allclose(with_handles.A[diag] - without.A[diag], 0.01**2 * K_HANDLE * np.eye(3)[None].repeat(2, 0),
                               rtol=1e-9)
    others = np.setdiff1d(np.arange(len(x)), idx)
    np.testing.assert_array_equal(with_handles.f[others], without.f[others])


def test_soft_handles_carry_the_hanging_cloth():
    """At rest, the handles' springs carry the cloth's weight: k * total drift = m g."""
    scene = example_scene("hanging", resolution=6, dt=0.01)
    m = scene.model
    held = m.pinned.clone()
    model = m.__class__(m.mesh, m.fabric, handles=[SoftHandle(held, K_HANDLE)], gravity=tuple(m.gravity.tolist()),
                        air_damping=5.0)
    solver = ImplicitEulerSolver(model)
    state = model.initial_state()
    for _ in range(300):
        state, _ = solver.step(state, 0.01)
    drift = (state.x[held] - model.mesh.x[held]).sum(0).numpy()
    weight = float(model.mass().sum()) * model.gravity.numpy()
    np.testing.assert_allclose(K_HANDLE * drift, weight, rtol=0.02, atol=2e-3 * np.abs(weight).max())


def test_a_vertex_cannot_be_pinned_and_soft_held():
    m = example_scene("hanging", resolution=4).model
    with pytest.raises(SceneError, match="both pinned and held"):
        m.__class__(m.mesh, m.fabric, pins=m.pins, handles=[SoftHandle(m.pinned.clone(), K_HANDLE)])
    with pytest.raises(SceneError, match="stiffness must be a positive"):
        m.__class__(m.mesh, m.fabric, handles=[SoftHandle(m.pinned.clone(), 0.0)])


def test_explicit_wind_leaves_the_matrix_alone():
    """ARCSim adds the wind force explicitly: same force, no damping in the solve's matrix."""
    obs = _soft_observation()
    x, v = obs.positions[4].copy(), np.zeros_like(obs.positions[4])
    explicit = obs.model(load_fabric("gray-interlock"))
    assert not explicit.wind.implicit
    _, sys_explicit = _system(explicit, x, v)
    explicit.wind.implicit = True
    _, sys_implicit = _system(explicit, x, v)
    np.testing.assert_array_equal(sys_explicit.f, sys_implicit.f)
    assert np.abs(sys_implicit.A - sys_explicit.A).max() > 0
    explicit.wind.density = 0.0
    _, sys_still = _system(explicit, x, v)
    np.testing.assert_allclose(sys_explicit.A, sys_still.A, rtol=0, atol=1e-15)


@pytest.mark.parametrize("part", ["params", "x0"])
def test_gradients_through_soft_handles_and_explicit_wind(part):
    obs = _soft_observation(resolution=5, duration=0.12)
    model = obs.model(load_fabric("gray-interlock"))
    sim = DiffSimulator(model, 0.01)
    x0 = torch.from_numpy(obs.positions[-1].copy())
    v0 = torch.from_numpy((obs.positions[-1] - obs.positions[-2]) / obs.frame_time)
    W = torch.randn(7, model.num_vertices, 3, dtype=F64, generator=torch.Generator().manual_seed(3))
    base = {"params": sim.parameters(), "x0": x0}

    def loss(inp):
        tr = sim.rollout(6, params=inp["params"], x0=inp["x0"], v0=v0)
        return (tr.x * W).sum()

    leaves = {k: t.clone().requires_grad_(k == part) for k, t in base.items()}
    loss(leaves).backward()
    g = torch.Generator().manual_seed(5)
    d = base[part] * torch.linspace(0.5, 1.5, len(base[part]), dtype=F64) if part == "params" else \
        1e-3 * torch.randn(base[part].shape, dtype=F64, generator=g)
    analytic = float((leaves[part].grad * d).sum())
    h = 1e-4 if part == "params" else 1e-3
    with torch.no_grad():
        fd = (float(loss(dict(base, **{part: base[part] + h * d}))) - float(loss(dict(base, **{part: base[part] - h * d})))) / (2 * h)
    assert analytic == pytest.approx(fd, rel=3e-3)


def test_observed_file_keeps_the_handle_stiffness_and_whether_dt_was_given(tmp_path):
    obs = _soft_observation(duration=0.08)
    obs.dt_given = False
    save_observed(tmp_path / "o.npz", obs)
    back = load_observed(tmp_path / "o.npz")
    from tryon.diff.observed import camera_only
    from tryon.diff.observed import REQUIRED_KEYS

    save_observed(tmp_path / "camera.npz", camera_only(obs))
    assert sorted(np.load(tmp_path / "camera.npz").files) == sorted(REQUIRED_KEYS)
    assert back.handle_stiffness == K_HANDLE and not back.dt_given
    assert "dt" not in np.load(tmp_path / "o.npz")


def test_time_step_choice_halves_until_the_early_motion_converges():
    obs = _soft_observation(resolution=5, duration=0.4)
    choice = choose_dt(obs, load_fabric("gray-interlock"))
    assert choice.converged
    dts = [dt for dt, _ in choice.checks]
    assert dts == sorted(dts, reverse=True) and all(np.isclose(a / b, 2.0) for a, b in zip(dts, dts[1:]))
    assert choice.checks[-1][1] < DT_TOLERANCE <= min(c for _, c in choice.checks[:-1]) if len(dts) > 1 else True
    assert np.isclose(choice.dt, dts[-1])
    strict = choose_dt(obs, load_fabric("gray-interlock"), tolerance=choice.checks[-1][1] / 4)
    assert strict.dt < choice.dt


def test_tryon_reproduces_an_arcsim_run_at_its_time_step():
    """The shipped ARCSim run with the coarse step (fast): tryon with the true fabric stays
    within 1 % of it, and within the same margin only with both of ARCSim's settings."""
    run = next(r for r in load_reference_runs() if r.name == "gray-interlock_dt0.02")
    obs = run.obs
    size = obs.cloth_size()

    def error(without=None):
        x = simulate_frames(variant_model(run, without), obs.num_frames, obs.steps_per_frame, obs.dt)
        return float(np.linalg.norm(x[1:] - obs.positions[1:], axis=-1).mean()) / size

    assert error() < 0.01
    assert error("explicit wind") > 2 * error()


def test_fidelity_bench_writes_records_and_pictures(tmp_path):
    """On a small tryon-made reference (ground truth included) the bench reproduces it."""
    ref = tmp_path / "ref"
    ref.mkdir()
    obs = _soft_observation(resolution=4, duration=0.16, dt=0.02)
    fab = load_fabric("gray-interlock")
    save_observed(ref / "gray-interlock_dt0.02.npz", obs)
    data = dict(np.load(ref / "gray-interlock_dt0.02.npz"))
    data.update(material="gray-interlock", material_density=float(fab.density),
                material_stretching=fab.stretching_data.numpy(), material_bending=fab.bending_data.numpy(),
                material_multipliers=np.ones(3))
    np.savez(ref / "gray-interlock_dt0.02.npz", **data)
    records = run_fidelity_bench(str(tmp_path / "f.json"), reference=str(ref))
    on_disk = json.loads((tmp_path / "f.json").read_text())
    assert len(on_disk) == len(records)
    own = next(r for r in records if r["role"] == "own")
    assert own["reference"] == "gray-interlock_dt0.02.npz" and own["dt"] == 0.02 and own["error"] < 1e-6
    assert {r.get("without") for r in records if r["role"] == "cause"} == {
        "soft handles", "explicit wind", "soft handles and explicit wind"}
    assert all(r["error"] > 0 for r in records if r["role"] == "cause")
    assert next(r for r in records if r["role"] == "summary")["within_1_percent"]
    assert (tmp_path / "f-gray-interlock_dt0.02.png").stat().st_size > 0
    assert (tmp_path / "f-gray-interlock_dt0.02-frames.png").stat().st_size > 0


def test_packaged_reference_set_is_complete():
    names = sorted(p.name for p in REFERENCE_DIR.glob("*.npz"))
    assert names == [f"{m}_dt{dt}.npz" for m in ("gray-interlock", "pink-ribbon-brown", "white-dots-on-blk")
                     for dt in ("0.005", "0.02")]


def test_momentum_balance_gives_density_and_handle_stiffness():
    """Internal forces cancel over the whole cloth: density and the handles' stiffness follow
    from the frames alone, whatever the elastic model."""
    from tryon.diff.momentum import momentum_estimate

    obs = _soft_observation(resolution=6, duration=0.6)
    fab = load_fabric("gray-interlock")
    est = momentum_estimate(obs, obs.model(load_fabric("11oz-black-denim")))
    assert est is not None
    assert est.density == pytest.approx(float(fab.density), rel=0.03)
    assert est.handle_stiffness == pytest.approx(K_HANDLE, rel=0.05)
    assert 0 < est.density_std < 0.05 * est.density
    hard = make_observed("gray-interlock", resolution=6, duration=0.6)
    assert momentum_estimate(hard, hard.model(fab)) is None


def test_fit_setup_for_a_camera_observation():
    """No dt, no handle stiffness: soft handles from the balance, density frozen at its
    estimate, the time step from the convergence check."""
    from tryon.diff.observed import camera_only
    from tryon.diff.fit import prepare_fit

    setup = prepare_fit(camera_only(_soft_observation(resolution=6, duration=0.6)))
    assert setup.obs.handle_stiffness == pytest.approx(K_HANDLE, rel=0.05)
    assert setup.frozen == ("density",)
    assert float(setup.start.density) == pytest.approx(float(load_fabric("gray-interlock").density), rel=0.03)
    assert setup.report["time_step"]["converged"] and setup.dt == setup.report["time_step"]["dt"]
    assert setup.report["handles"].startswith("soft")


def test_gauss_newton_fit_of_a_camera_observation(tmp_path):
    """fit-fabric on frames alone: density within the balance's accuracy, motion refit, and
    a report with the time-step check, the balance and the identifiability."""
    from tryon.diff.observed import camera_only
    from tryon.diff.fit import run_fit_fabric

    path = tmp_path / "obs.npz"
    save_observed(path, camera_only(_soft_observation(resolution=6, duration=0.6)))
    report = run_fit_fabric(str(path), str(tmp_path / "fit"), truth="gray-interlock", progress=False)
    assert report["method"] == "gauss-newton"
    assert report["density_error"] < 0.03
    assert report["simulation_error"] < 0.5 * report["start_simulation_error"]
    assert report["simulation_error_at_truth"] < report["start_simulation_error"]
    assert report["handles"].startswith("soft") and report["time_step"]["converged"]
    ident = report["identifiability"]
    assert set(ident["groups"]) == {"stretch_k0", "stretch_k1", "stretch_k2", "stretch_k3", "stretch_nonlinear",
                                    "bend_u", "bend_diagonal", "bend_v"}
    eig = [d["relative_eigenvalue"] for d in ident["directions"]]
    assert eig[0] == 1.0 and eig == sorted(eig, reverse=True)


def test_scene_files_can_ask_for_soft_handles_and_explicit_wind(tmp_path):
    from tryon.sim.scene import load_scene

    path = tmp_path / "arcsim.yaml"
    path.write_text("dt: 0.02\nduration: 0.1\ncloth:\n  grid: {resolution: [5, 5], size: [1.0, 1.0]}\n"
                    "  fabric: gray-interlock\n  handles:\n    - vertices: [top-left, top-right]\n      stiffness: 1000\n"
                    "    - vertices: [bottom-left]\n"
                    "wind: {velocity: [2, 2, 0], implicit: false}\n")
    scene = load_scene(path)
    m = scene.model
    assert [h.stiffness for h in m.handles] == [1000.0] and sorted(m.handles[0].vertices.tolist()) == [20, 24]
    assert m.pinned.tolist() == [0] and not m.wind.implicit
    solver = ImplicitEulerSolver(m)
    state = m.initial_state()
    for _ in range(5):
        state, _ = solver.step(state, scene.dt)
    assert np.abs(state.x[20].numpy() - m.mesh.x[20].numpy()).max() > 0  # the soft corner gives a little
    assert np.abs(state.x[0].numpy() - m.mesh.x[0].numpy()).max() == 0  # the pinned one does not
    path.write_text(path.read_text().replace("stiffness: 1000", "stiffness: -1"))
    with pytest.raises(SceneError, match="stiffness"):
        load_scene(path)
