"""Learning one direction of a mirror-symmetric task: worlds whose goal is negative see the task in a mirror.

A task is *mirror-symmetric* when a reflection of the scene maps it to itself with its goal's sign flipped: the
2-finger claw and its knob are symmetric about the xz-plane, so a world turning the knob by -θ is, in the mirror,
a world turning it by +θ (the fingers swapped, every joint angle and velocity negated, the fingertips' y negated).
:class:`MirrorGoal` writes the policy input ``"observation"`` of those worlds mirrored and mirrors the policy's
``"action"`` back before the env steps. Any policy, critic or normaliser behind it then sees only positive goals:
the policy is mirror-equivariant by construction, and a run cannot learn one direction and miss the other. The
reward and success are the env's, computed on the real state (the reflection leaves both unchanged).

A reflection of a vector is a :class:`SignedPermutation`: ``mirrored[..., i] = sign[i] * x[..., index[i]]``.
The task declares one per policy entry and one for its actions (:meth:`DexEnv.mirror_maps`); the transform
assembles the observation's from the env's policy keys.

Example:
    >>> import torch
    >>> swap = SignedPermutation((1, 0), (-1.0, -1.0))
    >>> swap(torch.tensor([[1.0, 2.0]]))
    tensor([[-2., -1.]])
    >>> swap(swap(torch.tensor([[1.0, 2.0]])))  # a reflection is its own inverse
    tensor([[1., 2.]])
"""

from __future__ import annotations

import dataclasses

import torch
from tensordict import TensorDictBase

from .transforms import StateTransform

__all__ = ["MirrorGoal", "SignedPermutation", "action_reflection", "mirrored_worlds", "reflect_mirrored", "sized"]


@dataclasses.dataclass(frozen=True)
class SignedPermutation:
    """``x -> sign * x[..., index]`` on the last dimension; a reflection when it is its own inverse."""

    index: tuple[int, ...]
    sign: tuple[float, ...]

    def __post_init__(self):
        if sorted(self.index) != list(range(len(self.index))) or len(self.sign) != len(self.index):
            raise ValueError(f"a signed permutation needs a permutation of 0..n-1 and n signs, got index "
                             f"{self.index} and sign {self.sign}")
        if any(s not in (-1.0, 1.0) for s in self.sign):
            raise ValueError(f"signs must be +-1, got {self.sign}")
        object.__setattr__(self, "_tensors", {})  # (dtype, device) -> (index, sign): built once, used every step

    @classmethod
    def negate(cls, width: int) -> "SignedPermutation":
        """Every entry negated, none moved (angles and torques about a mirrored hinge)."""
        return cls(tuple(range(width)), (-1.0,) * width)

    @classmethod
    def identity(cls, width: int) -> "SignedPermutation":
        """Nothing moved (features the reflection leaves unchanged, e.g. the time)."""
        return cls(tuple(range(width)), (1.0,) * width)

    @classmethod
    def concat(cls, parts: list["SignedPermutation"]) -> "SignedPermutation":
        """The reflection of a concatenation of vectors, each reflected by its part."""
        index, sign, offset = [], [], 0
        for part in parts:
            index += [offset + i for i in part.index]
            sign += list(part.sign)
            offset += len(part.index)
        return cls(tuple(index), tuple(sign))

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[-1] != len(self.index):
            raise ValueError(f"this reflection maps vectors of {len(self.index)} entries, got {x.shape[-1]}")
        key = (x.dtype, x.device)
        if key not in self._tensors:
            self._tensors[key] = (torch.as_tensor(self.index, device=x.device),
                                  torch.as_tensor(self.sign, dtype=x.dtype, device=x.device))
        index, sign = self._tensors[key]
        return x.index_select(-1, index) * sign


def sized(part, width: int, key) -> SignedPermutation:
    """A task's map of entry ``key``, ``width`` wide: a :class:`SignedPermutation`, or a function of the width
    (e.g. :meth:`SignedPermutation.negate` for a goal window) called with it; a width mismatch fails naming the key."""
    part = part if isinstance(part, SignedPermutation) else part(width)
    if len(part.index) != width:
        raise ValueError(f"the task's mirror of {key} has {len(part.index)} entries, the entry {width}")
    return part


def mirrored_worlds(td: TensorDictBase, goal_key=("task", "goal")) -> torch.Tensor:
    """[..., 1] bool: the worlds a mirrored task shows in the mirror (those whose goal is negative)."""
    return td.get(goal_key)[..., :1] < 0


def reflect_mirrored(td: TensorDictBase, x: torch.Tensor, reflection: SignedPermutation) -> torch.Tensor:
    """``x`` [..., n] with the mirrored worlds' rows reflected."""
    return torch.where(mirrored_worlds(td), reflection(x), x)


def action_reflection(task_env) -> SignedPermutation | None:
    """The action reflection a controller acting in the real scene (a scripted controller, a planner) applies
    to the mirrored worlds of ``task_env``'s task, so that the env reflects it back; ``None`` when the task is
    not mirrored (``task.mirror`` off)."""
    return task_env.mirror_maps()[1] if task_env.config.mirror else None


class MirrorGoal(StateTransform):
    """Mirror the policy input of worlds whose goal is negative, and their actions back (see the module
    docstring). Appended after the goal conditioning that assembles ``"observation"`` from ``policy_keys``."""

    def __init__(self, maps: dict, action: SignedPermutation, policy_keys: list):
        super().__init__(in_keys=["observation", ("task", "goal")], out_keys=["observation"],
                         in_keys_inv=["action"], out_keys_inv=["action"])
        self.maps, self.action_map, self.policy_keys = maps, action, list(policy_keys)
        missing = [k for k in self.policy_keys if k not in maps]
        if missing:
            raise ValueError(f"the task's mirror does not say how to reflect the policy entries {missing}")
        self._observation_map: SignedPermutation | None = None

    def observation_map(self) -> SignedPermutation:
        """The reflection of the whole ``"observation"``, assembled from the policy keys' maps (a map may be a
        function of the entry's width, e.g. :meth:`SignedPermutation.negate` for a goal window)."""
        if self._observation_map is None:
            spec, lead = self.parent.observation_spec, len(self.parent.batch_size)
            self._observation_map = SignedPermutation.concat([
                sized(self.maps[key], int(torch.Size(spec[key].shape[lead:]).numel()), key) for key in self.policy_keys])
        return self._observation_map

    def _call(self, td: TensorDictBase) -> TensorDictBase:
        td.set("observation", reflect_mirrored(td, td.get("observation"), self.observation_map()))
        return td

    def _inv_call(self, td: TensorDictBase) -> TensorDictBase:
        action = td.get("action", None)
        # an action of the wrong width passes through untouched: the env's own check names the bad field
        if isinstance(action, torch.Tensor) and action.shape[-1:] == (len(self.action_map.index),):
            td.set("action", reflect_mirrored(td, action, self.action_map))
        return td

