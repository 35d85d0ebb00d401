"""Motion control: the basket task's controllers and `tryon control`."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from tryon.cli import main
from tryon.diff.control import (BASKET_CENTER, BASKET_FLOOR, BASKET_HALF, BASKET_WALL, CLOTH, BasketTask, CornerPolicy,
                                basket_spec, interval_forces, optimise, point_mass_forces, run_control)
from tryon.diff.rollout import Controls
from tryon.errors import TryonError


@pytest.fixture(scope="module")
def task():
    return BasketTask(resolution=3, variant="flat", dt=0.05)


def test_direct_forces_are_deviations_from_carrying_the_weight(task):
    """u = 0: the four corners together carry the cloth's weight during the force time
    and nothing after; any u stays within F_max of that."""
    f0 = interval_forces(torch.zeros(6, 4, 3, dtype=torch.float64), task)
    weight = -task.total_mass * task.scene.model.gravity
    torch.testing.assert_close(f0[: task.force_steps].sum(1), weight.expand(task.force_steps, 3))
    assert float(f0[task.force_steps:].abs().max()) == 0.0
    f = interval_forces(torch.full((6, 4, 3), 50.0, dtype=torch.float64), task)
    assert float((f - f0).abs().max()) <= 0.02 + 1e-12


def test_point_mass_baseline_reaches_its_waypoints_as_a_point(task):
    u, sims = point_mass_forces(task, iterations=400)
    assert sims == 400
    steps, points = task.waypoint_steps()
    dt = task.scene.dt
    acc = interval_forces(u, task).sum(1) / task.total_mass + task.scene.model.gravity
    p, v = task.com(task.x0), torch.zeros(3, dtype=torch.float64)
    reached = []
    for k in range(task.steps):
        v = v + dt * acc[k]
        p = p + dt * v
        if k + 1 in steps.tolist():
            reached.append(p)
    reached = torch.stack(reached)
    assert float((reached[:-1] - points[:-1]).norm(dim=1).max()) < 0.05
    assert float((reached[-1, :2] - points[-1, :2]).norm()) < 0.05 and float(reached[-1, 2]) <= points[-1, 2]


def test_small_step_against_the_gradient_lowers_the_loss(task):
    """Through contact with the table and the whole rollout, a small step against the
    gradient must decrease the loss, for the direct forces and the policy's weights."""
    u = torch.full((6, 4, 3), 0.3, dtype=torch.float64, requires_grad=True)
    policy = CornerPolicy(task)
    torch.nn.init.normal_(policy.net[2].weight, std=0.1, generator=torch.Generator().manual_seed(0))
    cases = [([u], lambda: Controls(forces=interval_forces(u, task), force_vertices=task.corners)),
             (list(policy.parameters()), lambda: Controls(policy=policy, force_vertices=task.corners))]
    for params, controls in cases:
        loss = task.loss(task.rollout(controls()))
        grads = torch.autograd.grad(loss, params)
        norm = torch.sqrt(sum((g**2).sum() for g in grads))
        with torch.no_grad():
            for p, g in zip(params, grads):
                p -= 1e-3 * g / norm
            after = task.loss(task.rollout(controls()))
        assert float(after) < float(loss.detach())


def test_optimise_counts_its_samples(task):
    res = optimise(task, "direct", iterations=2, lr=0.003, progress=False)
    assert res.samples == 2 and len(res.history) == 2
    assert res.trajectory.shape == (task.steps + 1, 9, 3)


def test_policy_outputs_forces_only_during_the_force_time(task):
    policy = CornerPolicy(task)
    x, v = task.x0, torch.zeros_like(task.x0)
    torch.testing.assert_close(policy(0, x, v), task.hover.expand(4, 3))
    assert float(policy(task.force_steps, x, v).abs().max()) == 0.0


@pytest.mark.slow
def test_control_command_writes_report_and_preview(tmp_path):
    out = tmp_path / "basket"
    assert main(["control", "--example", "basket", "--out", str(out), "--iterations", "1", "--resolution", "3",
                 "--variant", "sloped", "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    modes = {r["mode"]: r for r in report["results"]}
    assert set(modes) == {"direct", "policy", "point-mass", "sampling"}
    assert modes["sampling"]["cloth_simulations"] == 1
    for r in modes.values():
        assert np.isfinite(r["final_distance_over_size"]) and r["variant"] == "sloped"
    assert modes["point-mass"]["cloth_simulations"] == 1
    assert (out / "preview_sloped.gif").read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    with pytest.raises(TryonError, match="unknown control example"):
        run_control("kite", str(tmp_path / "x"))


def test_sampling_baseline_spends_its_budget_and_keeps_the_best(task):
    from tryon.diff.control import SAMPLING_POPULATION, sample_search

    res = sample_search(task, SAMPLING_POPULATION + 2, seed=1)
    assert res.samples == res.cloth_simulations == len(res.history) == SAMPLING_POPULATION + 2
    assert res.trajectory.shape[0] == task.steps + 1 and np.isfinite(res.distance_over_size)
    with pytest.raises(TryonError, match="at least 1 sample"):
        sample_search(task, 0)


def test_sloped_basket_is_a_hopper_that_catches_a_dropped_cloth():
    """The sloped variant's basket is an open hopper: a cloth dropped over its opening comes
    to rest on the sloped walls inside it (with no basket it would fall through, as there is
    no floor), above the apex and below the rim, about a third of its size from the apex
    (the task's score there is 0.36: a crumpled cloth cannot reach the apex)."""
    from tryon.sim.integrator import ImplicitEulerSolver
    from tryon.sim.loop import steps
    from tryon.sim.scene import parse_scene

    spec = basket_spec(5, "sloped")
    assert [o["type"] for o in spec["obstacles"]] == ["box", "box", "pyramid"]
    bx, by = BASKET_CENTER
    spec["cloth"]["grid"]["origin"] = [bx - 0.04 - CLOTH / 2, by - CLOTH / 2, 0.35]
    spec["duration"] = 1.5
    scene = parse_scene(spec)
    state = scene.model.initial_state()
    for rec in steps(ImplicitEulerSolver(scene.model, scene.options), state, scene.dt, stop=scene.num_steps):
        state = rec.state
    x = state.x.numpy()
    mass = scene.model.mass().detach().numpy()
    com = (mass[:, None] * x).sum(0) / mass.sum()
    assert np.abs(com[:2] - np.array(BASKET_CENTER)).max() < BASKET_HALF / 2
    assert BASKET_FLOOR + 0.05 < com[2] < BASKET_FLOOR + BASKET_WALL
    apex = np.array([*BASKET_CENTER, BASKET_FLOOR])
    assert 0.25 < np.linalg.norm(com - apex) / np.hypot(CLOTH, CLOTH) < 0.45
    assert np.linalg.norm(state.v.numpy(), axis=1).max() < 0.05  # at rest on the walls
