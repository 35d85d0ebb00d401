"""The differentiable step records the plain solver's step: composed of the same public
phases, its forward result equals `ImplicitEulerSolver.step` to round-off on scenes with
contact, friction, impact zones and pins."""

import numpy as np
import pytest
import torch

from tryon.diff.step import TapedSolver
from tryon.sim import ImplicitEulerSolver, StepOptions
from tryon.sim.linear import HAVE_CHOLMOD
from tryon.sim.scene import example_scene

SCENES = [("sphere-drop", 8, 30), ("table", 8, 30), ("hanging", 6, 10), ("pyramid", 8, 30)]


@pytest.mark.parametrize("name,resolution,steps", SCENES)
def test_taped_step_equals_plain_step(name, resolution, steps):
    scene = example_scene(name, resolution)
    model, dt = scene.model, scene.dt
    direct = "cholmod" if HAVE_CHOLMOD else "splu"
    plain = ImplicitEulerSolver(model, StepOptions(linear_solver=direct))
    taped = TapedSolver(model, StepOptions())
    state = model.initial_state()
    seen = {"contacts": 0, "impacts": 0, "pinned": bool(plain.pinned_mask.any())}
    for _ in range(steps):
        x, v = state.x.numpy(), state.v.numpy()
        targets = model.pin_targets(state.t + dt).numpy()
        tape = taped.taped_step(x, v, state.t, dt, None, None, targets, allow_fallback=False)
        state, stats = plain.step(state, dt)
        if stats.substeps != 1:  # a retried step has no single tape to compare
            continue
        assert tape.ok
        assert np.allclose(tape.z, state.x.numpy(), rtol=0, atol=1e-12)
        assert np.allclose(tape.v_new, state.v.numpy(), rtol=0, atol=1e-9)
        seen["contacts"] += stats.contacts
        seen["impacts"] += tape.impacts
    if name in ("sphere-drop", "table", "pyramid"):
        assert seen["contacts"] > 0  # the comparison covered contact and friction
    if name == "hanging":
        assert seen["pinned"]


def test_taped_forward_matches_with_an_external_force_and_wind():
    scene = example_scene("hanging", 6)
    model, dt = scene.model, scene.dt
    direct = "cholmod" if HAVE_CHOLMOD else "splu"
    plain = ImplicitEulerSolver(model, StepOptions(linear_solver=direct))
    taped = TapedSolver(model)
    from tryon.sim import Control

    state = model.initial_state()
    force = np.zeros((model.num_vertices, 3))
    force[:, 1] = 0.01
    wind = np.array([1.0, 0.5, 0.0])
    control = Control(torch.from_numpy(force), torch.from_numpy(wind))
    tape = taped.taped_step(state.x.numpy(), state.v.numpy(), 0.0, dt, force, wind,
                            model.pin_targets(dt).numpy(), allow_fallback=False)
    new, _ = plain.step(state, dt, control)
    assert np.allclose(tape.z, new.x.numpy(), rtol=0, atol=1e-12)
