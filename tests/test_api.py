"""The simulation core's public surface (``dexmots_rl.sim``): the names it exports and the signatures of its
entry points, pinned so that a change to either is deliberate (options after the scene are keyword-only)."""

from __future__ import annotations

import inspect
import typing

import pytest
import torch

import dexmots_rl.sim as sim
from dexmots_rl.sim import ArticulatedStepOutput, StepOutput

PUBLIC = {
    # scenes
    "AssetError", "ContactParams", "SceneModel", "ArticulatedScene", "ObjectTree", "HINGE", "SLIDE", "TableContact",
    "joint_param_names", "load_scene", "load_variants", "load_object_tree",
    # simulators and their step
    "make_simulator", "HandSimulator", "Simulator", "ArticulatedSimulator", "ObjectSimulator", "Control", "StepOutput",
    "ArticulatedStepOutput", "SimStep", "TapeTrajectory", "Trajectory", "check_device", "cpu_threads",
    # drawing
    "make_renderer", "Camera", "Renderer", "MeshRenderer", "LABEL_TABLE", "SceneGeometry", "MeshPart",
    "scene_geometry", "recorded_body_names", "box_mesh", "quat_to_mat", "transform", "ROLE_RGBA", "GOAL_RGBA", "STATIC",
    # compilation
    "compile_scene", "warp_versions",
}

POSITIONAL, KEYWORD = inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY
# entry point -> its parameters: (name, kind, default) in order (``inspect.Parameter.empty``: required)
REQUIRED = inspect.Parameter.empty
SIGNATURES = {
    "load_scene": [("path", POSITIONAL, REQUIRED), ("contact", KEYWORD, None), ("articulated", KEYWORD, False)],
    "load_variants": [("paths", POSITIONAL, REQUIRED), ("contact", KEYWORD, None)],
    "load_object_tree": [("asset", POSITIONAL, REQUIRED), ("timestep", KEYWORD, 1.0 / 960.0)],
    "make_simulator": [("scene", POSITIONAL, REQUIRED), ("num_worlds", KEYWORD, REQUIRED), ("device", KEYWORD, "cpu"),
                       ("dtype", KEYWORD, torch.float32), ("substeps", KEYWORD, 16), ("dt", KEYWORD, None),
                       ("contact", KEYWORD, None), ("adjoint_clip", KEYWORD, None)],
    "make_renderer": [("scene", POSITIONAL, REQUIRED), ("height", KEYWORD, 64), ("width", KEYWORD, 64),
                      ("camera", KEYWORD, None), ("device", KEYWORD, "cpu"), ("asset", KEYWORD, None)],
    "compile_scene": [("scene", POSITIONAL, REQUIRED), ("device", KEYWORD, "cuda"), ("arch", KEYWORD, 90),
                      ("dtypes", KEYWORD, (torch.float32,)), ("contact", KEYWORD, None), ("render", KEYWORD, True)],
    "check_device": [("device", POSITIONAL, REQUIRED)],
    "Simulator": [("scene", POSITIONAL, REQUIRED), ("num_worlds", POSITIONAL, REQUIRED), ("device", KEYWORD, "cpu"),
                  ("dtype", KEYWORD, torch.float32), ("substeps", KEYWORD, 16), ("dt", KEYWORD, None),
                  ("contact", KEYWORD, None), ("adjoint_clip", KEYWORD, None)],
    "ArticulatedSimulator": [("scene", POSITIONAL, REQUIRED), ("num_worlds", POSITIONAL, REQUIRED),
                             ("device", KEYWORD, "cpu"), ("dtype", KEYWORD, torch.float32), ("substeps", KEYWORD, 16),
                             ("dt", KEYWORD, None), ("contact", KEYWORD, None), ("table", KEYWORD, None),
                             ("adjoint_clip", KEYWORD, None)],
}
# every simulator steps the same way: the state, the control and the named parameters, in that order
STEP = [("joint_q", POSITIONAL, REQUIRED), ("joint_qd", POSITIONAL, REQUIRED), ("control", POSITIONAL, REQUIRED),
        ("params", POSITIONAL, REQUIRED)]


def _parameters(fn) -> list[tuple]:
    params = inspect.signature(fn).parameters.values()
    return [(p.name, p.kind, p.default) for p in params if p.name != "self"]


def test_the_public_names_are_pinned():
    assert len(sim.__all__) == len(set(sim.__all__))
    assert set(sim.__all__) == PUBLIC
    assert all(hasattr(sim, name) for name in PUBLIC)


@pytest.mark.parametrize("name", sorted(SIGNATURES))
def test_entry_point_signatures_are_pinned(name):
    assert _parameters(getattr(sim, name)) == SIGNATURES[name]


@pytest.mark.parametrize("name", ["HandSimulator", "Simulator", "ArticulatedSimulator"])
def test_every_simulator_steps_and_observes_alike(name):
    cls = getattr(sim, name)
    assert issubclass(cls, sim.HandSimulator)
    assert _parameters(cls.step) == STEP
    assert [p[0] for p in _parameters(cls.observe)] == ["joint_q", "joint_qd", "params"]
    assert issubclass(cls.output_type, StepOutput)


@pytest.mark.parametrize("name", ["Simulator", "ArticulatedSimulator"])
def test_the_tape_protocol_is_what_the_trajectories_implement(name):
    traj = typing.get_type_hints(getattr(sim, name).new_trajectory)["return"]  # the simulator's trajectory class
    assert _parameters(sim.TapeTrajectory.load)  # a Protocol's methods keep their signatures
    for method in ("load", "forward", "outputs", "backward"):
        want = [p[0] for p in _parameters(getattr(sim.TapeTrajectory, method))]
        assert [p[0] for p in _parameters(getattr(traj, method))] == want, (traj, method)


@pytest.mark.parametrize("output_type", [StepOutput, ArticulatedStepOutput])
def test_a_step_outputs_unknown_field_is_an_attribute_error(output_type):
    out = output_type(tuple(torch.zeros(2, i + 1) for i in range(len(output_type.names))))
    assert out.joint_q.shape == (2, 1) and out.fingertips.shape == (2, 6)
    with pytest.raises(AttributeError, match="no field 'joint_velocity'.*joint_q, joint_qd"):
        out.joint_velocity  # noqa: B018
    assert not hasattr(out, "joint_velocity") and getattr(out, "joint_velocity", None) is None
    assert set(output_type.names) <= set(dir(out))
