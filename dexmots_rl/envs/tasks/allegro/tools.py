"""The operable-tool tasks: one registered task per class of the object library, each ``operate`` on that class.

Every task is :mod:`.operate_object` with its class's object and defaults: the object stands free on the
table (or is fixed, for fixtures: valve, drawer, door handle), the hand starts near where a person holds the
tool, and success needs the operated joint within its band of the goal at the episode end *and* a free base
moved less than 2 cm and tilted less than 0.2 rad (a tool pushed away, knocked over or dropped fails). The
physics of each tool (its joint's range, spring, damping, friction; the object's mass and sizes) comes from
its class's generator (:mod:`dexmots_rl.assets.objects.generators`), never from the task.

======================  ===============  ======================================================================
task                    object            what the hand does
======================  ===============  ======================================================================
``spray_bottle``        spray_bottle_a    holds the bottle and pulls its sprung trigger to 90 % of its travel
``scissors``            scissors_a        opens the closed scissors: spreads the finger rings on their pivot
``stapler``             stapler_a         presses the sprung arm down
``pump_dispenser``      pump_dispenser_a  presses the sprung pump head down
``jar``                 jar_a             turns the lid (friction, no spring) while holding the jar
``valve``               valve_a           turns a fixed valve's handwheel
``drawer``              drawer_a          pulls a fixed drawer open by its handle
``pliers``              pliers_a          closes the handles on their pivot
``door_handle``         door_handle_a     presses a fixed door handle's sprung lever down
======================  ===============  ======================================================================

Example:
    >>> from dexmots_rl.envs import make_env
    >>> env = make_env("drawer", num_envs=2, seed=0)
    >>> env.base_env.joint_name
    'drawer'
"""

from __future__ import annotations

import dataclasses

from ...registry import register_task
from .operate_object import OperateObjectConfig, OperateObjectEnv, object_names

__all__ = ["ToolConfig", "SprayBottleConfig", "ScissorsConfig", "StaplerConfig", "PumpDispenserConfig", "JarConfig", "ValveConfig", "DrawerConfig", "PliersConfig", "DoorHandleConfig",
           "TOOL_TASKS"]


@dataclasses.dataclass
class ToolConfig(OperateObjectConfig):
    """A tool task's config: its ``object`` and ``objects`` are of the class of its default object (a library
    instance of that class, or a .urdf path); ``operate`` takes any class."""

    def validate(self) -> "ToolConfig":
        from ....assets.objects import INSTANCES

        super().validate()
        tool_class = INSTANCES[type(self).object][0]
        given = [("object", self.object)]
        if isinstance(self.objects, (str, list, tuple)):
            given += [("objects", name) for name in object_names(self.objects, self.object)]
        for field, name in given:
            if isinstance(name, str) and name in INSTANCES and INSTANCES[name][0] != tool_class:
                ours = ", ".join(n for n, (c, _) in INSTANCES.items() if c == tool_class)
                raise ValueError(f"task.{field}: {name!r} is a {INSTANCES[name][0]}; the {self.name} task takes a "
                                 f"{tool_class}: {ours} (or a .urdf path; task=operate takes any class)")
        return self


@dataclasses.dataclass
class SprayBottleConfig(ToolConfig):
    name: str = "spray_bottle"
    object: str = "spray_bottle_a"


@dataclasses.dataclass
class ScissorsConfig(ToolConfig):
    name: str = "scissors"
    object: str = "scissors_a"


@dataclasses.dataclass
class StaplerConfig(ToolConfig):
    name: str = "stapler"
    object: str = "stapler_a"


@dataclasses.dataclass
class PumpDispenserConfig(ToolConfig):
    name: str = "pump_dispenser"
    object: str = "pump_dispenser_a"


@dataclasses.dataclass
class JarConfig(ToolConfig):
    name: str = "jar"
    object: str = "jar_a"


@dataclasses.dataclass
class ValveConfig(ToolConfig):
    name: str = "valve"
    object: str = "valve_a"


@dataclasses.dataclass
class DrawerConfig(ToolConfig):
    name: str = "drawer"
    object: str = "drawer_a"


@dataclasses.dataclass
class PliersConfig(ToolConfig):
    name: str = "pliers"
    object: str = "pliers_a"


@dataclasses.dataclass
class DoorHandleConfig(ToolConfig):
    name: str = "door_handle"
    object: str = "door_handle_a"


TOOL_TASKS = {config.name: config for config in (
    SprayBottleConfig, ScissorsConfig, StaplerConfig, PumpDispenserConfig, JarConfig, ValveConfig, DrawerConfig,
    PliersConfig, DoorHandleConfig)}  # task name -> its config class (one per library class)

for _name, _config in TOOL_TASKS.items():
    register_task(_name, OperateObjectEnv, _config)
