"""The cloth simulator: what to simulate (`ClothModel`, fixed during a run), where it is
(`ClothState`), its inputs (`Control`), the solver whose `step` is the only place time
advances (`ImplicitEulerSolver`), scenes (`Scene`, `load_scene`, `example_scene`) and the
run loop (`run`, `steps`, with observers such as `FrameRecorder` and `SettleTest`).

    from tryon.sim import ImplicitEulerSolver, FrameRecorder, example_scene, run

    scene = example_scene("sphere-drop", 32)
    solver = ImplicitEulerSolver(scene.model, scene.options)
    frames = FrameRecorder(scene.steps_per_frame, scene.num_steps, first=scene.model.initial_state())
    outcome = run(solver, scene.model.initial_state(), scene.dt, until=scene.num_steps, observers=[frames])
"""

from tryon.sim.integrator import ImplicitEulerSolver, StepOptions, StepStats, StepSystem
from tryon.sim.loop import FrameRecorder, RunOutcome, SettleTest, StepRecord, run, steps
from tryon.sim.model import ClothModel, ClothState, CollisionSettings, Control, PinGroup, Wind
from tryon.sim.scene import Scene, example_scene, load_scene, parse_scene

__all__ = [
    "ClothModel",
    "ClothState",
    "CollisionSettings",
    "Control",
    "FrameRecorder",
    "ImplicitEulerSolver",
    "PinGroup",
    "RunOutcome",
    "Scene",
    "SettleTest",
    "StepOptions",
    "StepRecord",
    "StepStats",
    "StepSystem",
    "Wind",
    "example_scene",
    "load_scene",
    "parse_scene",
    "run",
    "steps",
]
