"""Dynamics: integrator exactness, pins and handles, energy behaviour, solvers, friction."""

import numpy as np
import pytest
import torch

from tryon.fabric import load_fabric
from tryon.sim.integrator import ImplicitEulerSolver, StepOptions
from tryon.sim.linear import HAVE_CHOLMOD, BlockPattern, filtered_pcg
from tryon.sim.mesh import grid_mesh
from tryon.sim.model import ClothModel, CollisionSettings, PinGroup, Wind
from tryon.sim.obstacles import Motion, plane
from tryon.sim.scene import example_scene


def _free_cloth(res=6, **kw):
    mesh = grid_mesh((res, res), size=(0.5, 0.5), origin=(0, 0, 1.0))
    return ClothModel(mesh, load_fabric("gray-interlock"), **kw)


@pytest.mark.parametrize("kind,atol", [("splu", 1e-12), ("pcg", 1e-6)])
def test_free_fall_is_exact_for_an_unstressed_cloth(kind, atol):
    model = _free_cloth()
    solver = ImplicitEulerSolver(model, StepOptions(linear_solver=kind))
    s0 = model.initial_state()
    dt = 0.01
    s1, _ = solver.step(s0, dt)
    g = torch.tensor([0, 0, -9.8], dtype=torch.float64)
    assert torch.allclose(s1.v, dt * g.expand_as(s1.v), atol=atol / dt)
    assert torch.allclose(s1.x, s0.x + dt * dt * g, atol=atol)


def test_pins_and_moving_handles_follow_exactly():
    mesh = grid_mesh((6, 6), size=(0.5, 0.5), origin=(0, 0, 1.0))
    motion = Motion(velocity=np.array([0.0, 0.0, 0.2]))
    pins = [PinGroup(torch.tensor([0])), PinGroup(torch.tensor([5]), motion)]
    model = ClothModel(mesh, load_fabric("gray-interlock"), pins=pins)
    solver = ImplicitEulerSolver(model)
    s = model.initial_state()
    for _ in range(10):
        s, _ = solver.step(s, 0.01)
    assert torch.allclose(s.x[0], mesh.x[0])
    assert torch.allclose(s.x[5], mesh.x[5] + torch.tensor([0, 0, 0.2 * 0.1], dtype=torch.float64), atol=1e-12)


def _energy(model, x, v):
    from tryon.sim.forces.bending import bending_forces
    from tryon.sim.forces.membrane import membrane_forces

    m = model.mass().numpy()
    e_mem, _, _ = membrane_forces(x, model.faces, model.Dm_inv, model.rest_area, model.fabric.stretching_stiffness, with_hessian=False)
    e_bend, _, _ = bending_forces(x, model.hinges, model.hinge_rest_theta, model.hinge_area_sum, model.hinge_edge_dir_uv, model.fabric.bending_stiffness, with_hessian=False)
    kinetic = 0.5 * float((m[:, None] * v.numpy() ** 2).sum())
    potential = float((m * 9.8 * x[:, 2].numpy()).sum())
    return kinetic + potential + float(e_mem.sum()) + float(e_bend.sum())


def test_implicit_euler_does_not_gain_energy():
    mesh = grid_mesh((8, 8), size=(0.5, 0.5), origin=(0, 0, 1.0))
    model = ClothModel(mesh, load_fabric("gray-interlock"), pins=[PinGroup(torch.tensor([56, 63]))])
    solver = ImplicitEulerSolver(model)
    s = model.initial_state()
    energies = [_energy(model, s.x, s.v)]
    for _ in range(60):
        s, _ = solver.step(s, 0.01)
        energies.append(_energy(model, s.x, s.v))
    e = np.array(energies)
    assert np.all(np.diff(e) <= 1e-9 * np.abs(e).max() + 1e-12)  # backward Euler dissipates
    assert e[-1] < e[0]


@pytest.mark.parametrize("kind", ["splu", "pcg"] + (["cholmod"] if HAVE_CHOLMOD else []))
def test_linear_solvers_agree(kind):
    scene = example_scene("hanging", 10, dt=0.02)
    ref = ImplicitEulerSolver(scene.model, StepOptions(linear_solver="splu"))
    other = ImplicitEulerSolver(scene.model, StepOptions(linear_solver=kind, pcg_tol=1e-12))
    s = scene.model.initial_state()
    for _ in range(5):
        s, _ = ref.step(s, 0.02)
    a, _ = ref.step(s, 0.02)
    b, _ = other.step(s, 0.02)
    assert torch.allclose(a.x, b.x, atol=1e-9)


def test_pcg_is_the_same_on_one_thread_and_on_two(on_numba_threads):
    """The solver's loops run on numba's threads; its chunked dot products keep the
    iterates bit-identical whatever the thread count (small chunks: many per thread)."""
    scene = example_scene("hanging", 24, dt=0.02)
    solver = ImplicitEulerSolver(scene.model, StepOptions(linear_solver="pcg"))
    state = scene.model.initial_state()
    obstacles = scene.model.obstacles.vertices_at(0.0)
    system = solver.assemble(state, 0.02, None, None, obstacles, obstacles)
    blocks, rhs = system.A, system.rhs
    pattern: BlockPattern = solver.pattern
    free = ~solver.pinned_mask

    def solve(threads):
        x = np.zeros((pattern.n, 3))
        return filtered_pcg(pattern.indptr, pattern.indices, blocks, pattern.diag_block, rhs, x, free, 1e-10, 5000,
                            64), x

    results = on_numba_threads(solve)
    assert 0 < results[0][0] < 5000
    assert results[1][0] == results[0][0] and np.array_equal(results[1][1], results[0][1])
    A = pattern.to_csc(blocks).toarray().reshape(pattern.n, 3, pattern.n, 3)
    residual = np.einsum("iajb,jb->ia", A, results[0][1])[free] - rhs[free]
    assert np.linalg.norm(residual) <= 1e-8 * np.linalg.norm(rhs[free])


def test_wind_pushes_cloth_downwind():
    calm = _free_cloth()
    windy = _free_cloth(wind=Wind(velocity=(0.0, 0.0, 5.0)))
    s_calm, s_wind = calm.initial_state(), windy.initial_state()
    sc, sw = ImplicitEulerSolver(calm), ImplicitEulerSolver(windy)
    for _ in range(5):
        s_calm, _ = sc.step(s_calm, 0.01)
        s_wind, _ = sw.step(s_wind, 0.01)
    assert float(s_wind.x[:, 2].mean()) > float(s_calm.x[:, 2].mean()) + 1e-4


@pytest.mark.parametrize("mu,slides", [(0.2, True), (0.9, False)])
def test_coulomb_friction_on_a_slope(mu, slides):
    """A cloth patch on a 30 degree slope slides if mu < tan(30deg) = 0.577 and sticks otherwise."""
    angle = np.deg2rad(30)
    normal = np.array([0.0, -np.sin(angle), np.cos(angle)])
    slope = plane([0, 0, 0], normal, size=3.0, divisions=2)
    mesh = grid_mesh((5, 5), size=(0.2, 0.2), origin=(-0.1, -0.1, 0.0))
    uphill = np.array([0.0, np.cos(angle), np.sin(angle)])
    rot = np.stack([[1.0, 0, 0], uphill, normal], 1)  # cloth lies in the slope plane
    x = mesh.x.numpy() @ rot.T + 0.004 * normal
    from tryon.sim.mesh import ClothMesh

    cloth = ClothMesh(torch.from_numpy(x), mesh.uv, mesh.faces)
    model = ClothModel(cloth, load_fabric("11oz-black-denim"), obstacles=[slope],
                       collision=CollisionSettings(friction=mu, self_collision=False))
    solver = ImplicitEulerSolver(model)
    s = model.initial_state()
    speeds = []
    for _ in range(40):
        s, _ = solver.step(s, 0.01)
        speeds.append(float((s.v.numpy() @ uphill).mean()))
    travel = float(((s.x - cloth.x).numpy() @ uphill).mean())
    if slides:
        # kinetic friction: downhill acceleration g (sin a - mu cos a)
        accel = -(speeds[-1] - speeds[-11]) / 0.1
        assert accel == pytest.approx(9.8 * (np.sin(angle) - mu * np.cos(angle)), rel=0.1)
        assert travel < -0.05
    else:
        assert abs(travel) < 1e-3 and abs(speeds[-1]) < 1e-3
