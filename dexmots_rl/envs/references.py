"""Per-world object-centric references: a bank of planned trajectories, looked up by step counter.

A *bank* is a TensorDict ``[M, T]`` of M :class:`~dexmots_rl.trajectories.PoseWrenchTrajectory` rows
(``pose`` [7], ``joint_q`` [K], ``wrench`` [6], ``joint_torque`` [K]); plans of different lengths are padded
by repeating their last row (the object holds its final pose). At reset every world draws one plan
(``("task", "ref_index")``); after ``k`` env steps its reference is row ``k`` of that plan (clamped to the
last row). Banks come from ``dexmots-plan`` (a directory of ``.pt`` files or one file) or from a list of
trajectories.

Example:
    >>> import torch
    >>> from dexmots_rl.trajectories import PoseWrenchTrajectory
    >>> quat = torch.tensor([[1.0, 0, 0, 0]] * 3)
    >>> plan = PoseWrenchTrajectory(torch.zeros(3, 3), quat, torch.zeros(3, 6), dt=0.1,
    ...                             joint_q=torch.tensor([[0.0], [0.5], [1.0]]))
    >>> bank = load_reference_bank([plan])
    >>> lookup(bank, torch.tensor([[0]]), torch.tensor([[1, 2, 7]]))["joint_q"].flatten().tolist()
    [0.5, 1.0, 1.0]
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import torch
from tensordict import TensorDict

__all__ = ["DT_TOLERANCE", "MAX_ABS_COORDINATE", "MAX_ABS_WRENCH", "check_reference_values", "load_reference_bank",
           "lookup"]

# Sanity bounds of a plan an env accepts: 100 rad is ~16 turns of a knob and 100 m is far outside any
# scene; a plan past them is corrupt or mis-scaled (a 3.46e8 rad reference was once accepted silently).
MAX_ABS_COORDINATE = 100.0
MAX_ABS_WRENCH = 1.0e6  # N / N m
# a plan's dt and the env's agree to float32 rounding (the simulator keeps its step in float32: 1/60 is 0.0166666667)
DT_TOLERANCE = 1e-6


def check_reference_values(plan, source: str = "plan") -> None:
    """``ValueError`` naming the field when a plan holds non-finite or absurd values (see the bounds)."""
    limits = {"pos": MAX_ABS_COORDINATE, "joint_q": MAX_ABS_COORDINATE, "wrench": MAX_ABS_WRENCH,
              "joint_torque": MAX_ABS_WRENCH}
    for name, bound in limits.items():
        value = getattr(plan, name)
        if value.numel() == 0:
            continue
        if not bool(torch.isfinite(value).all()):
            raise ValueError(f"references: {source}: field {name!r} contains non-finite values")
        worst = float(value.abs().max())
        if worst > bound:
            raise ValueError(f"references: {source}: field {name!r} reaches |{worst:.4g}| > {bound:g}; "
                             "the plan is corrupt or mis-scaled")


def _trajectories(src) -> list:
    from ..trajectories import PoseWrenchTrajectory

    if isinstance(src, PoseWrenchTrajectory):
        return [src]
    if isinstance(src, (str, os.PathLike)):
        path = Path(src)
        if path.is_dir():
            files = sorted(path.glob("*.pt"))
            if not files:
                raise ValueError(f"references: no .pt plan files in directory {path}")
            return [PoseWrenchTrajectory.load(f) for f in files]
        return [PoseWrenchTrajectory.load(path)]
    if isinstance(src, Sequence) and len(src) and all(isinstance(t, PoseWrenchTrajectory) for t in src):
        return list(src)
    raise ValueError(f"references must be a plan file, a directory of plans or a non-empty list of "
                     f"PoseWrenchTrajectory, got {type(src).__name__}")


def load_reference_bank(src, dtype: torch.dtype = torch.float32, device="cpu", dt: float | None = None) -> TensorDict:
    """Stack plans into a bank ``[M, T]`` (see the module docstring); all plans must share K and dt, and with
    ``dt`` (the env's step, s) have that dt: row ``k`` is the reference after ``k`` steps of the env, so a
    plan of another step would be followed at the wrong speed."""
    plans = _trajectories(src)
    for i, plan in enumerate(plans):
        source = str(src) if isinstance(src, (str, os.PathLike)) else f"plan {i}"
        check_reference_values(plan, source)
        if dt is not None and not math.isclose(plan.dt, dt, rel_tol=DT_TOLERANCE):
            raise ValueError(f"references: {source} was planned with dt {plan.dt:.6g} s, the env steps dt "
                             f"{dt:.6g} s; plan again with the env's step (dexmots-plan)")
    ks = {t.num_joints for t in plans}
    dts = {round(t.dt, 9) for t in plans}
    if len(ks) != 1 or len(dts) != 1:
        raise ValueError(f"references: plans disagree on articulation size {sorted(ks)} or dt {sorted(dts)}")
    horizon = max(t.horizon for t in plans)
    rows = []
    for t in plans:
        padded = t.slice(0, horizon)
        rows.append(TensorDict({"pose": padded.poses, "joint_q": padded.joint_q, "wrench": padded.wrench,
                                "joint_torque": padded.joint_torque}, batch_size=[horizon]))
    return torch.stack(rows).to(device=device, dtype=dtype)


def lookup(bank: TensorDict, ref_index: torch.Tensor, steps: torch.Tensor) -> TensorDict:
    """Rows ``steps`` [N, H] (clamped to the plan length) of plans ``ref_index`` [N, 1]: a TensorDict [N, H]."""
    m, horizon = bank.batch_size
    idx = ref_index.reshape(-1, 1).clamp(0, m - 1).expand_as(steps)
    return bank[idx, steps.clamp(0, horizon - 1)]
