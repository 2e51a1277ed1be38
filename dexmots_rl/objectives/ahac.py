"""Adaptive horizon for SHAC (AHAC: Georgiev et al., ICML 2024; DexMOTS paper §6).

AHAC picks the rollout horizon so that stiff contact, whose gradients are discontinuous and noisy, stays
within a budget: a dual variable grows while the per-step contact force exceeds the threshold ``C̄`` and
shrinks when it stays below it, and the horizon shortens as the dual grows. Public AHAC code does this in
two ways, both available here:

* **dual-adapted horizon** (:meth:`AdaptiveHorizon.update`, :attr:`AdaptiveHorizon.horizon`): the length
  of the *next* rollout;
* **contact truncation** (:meth:`AdaptiveHorizon.truncate_rollout`): cut the graph of the *current* rollout
  before the first step with stiff contact, so that no gradient goes through it.

The rule implemented (everything per call of :meth:`~AdaptiveHorizon.update`, i.e. once per rollout)::

    a[n, t]  = ‖c[n, t]‖                           contact-force norm of world n at step t
    s_t      = mean_n a[n, t]  (or max_n, world_reduction="max"; non-finite entries ignored)
    s        = mean_t s_t
    ν       <- clip(ν + lr · (s − C̄), 0, ν_max)     projected dual ascent, ν_max = (H_max − H_min) / κ
    H        = clip(round(H_max − κ · ν), H_min, H_max)

``κ`` (``steps_per_dual``) converts the dual into horizon steps. Bounding ``ν`` by ``ν_max`` (the value at
which ``H`` reaches ``H_min``) is anti-windup: after a long stiff phase the horizon starts growing as soon as
contact falls below ``C̄`` instead of first unwinding an unbounded dual. With the defaults (lr 5e-4,
C̄ = 500, κ = 1) a sustained mean force of 1000 shortens the horizon by one step every 4 rollouts.

Relation to the public AHAC code: it keeps one dual per horizon step (``λ_t += lr (mean_n c_t − C̄)``) and
moves a continuous horizon by their sum. A single projected dual mapped directly onto ``H`` has the same
fixed point (mean stiff contact at ``C̄``), is monotone in the contact history, and is trivial to test and to
checkpoint; the per-world asynchronous truncation of that code is replaced by the batch-prefix cut above.

**Gradient-health horizon** (``clip_share_target``, off by default; :meth:`AdaptiveHorizon.update_clip_share`):
the contact force is a proxy for where gradients through contact stop being informative. Where it is a poor
one (on the jar the mean force stays at 1–2 N while the first-order gradient disagrees with a zeroth-order
estimate beyond two steps and the adjoint cap fires on 10–19 % of world-steps), the measured symptom can drive
the horizon instead. A second dual, on the share ``q`` of world-steps whose adjoint the simulator capped in the
last backward pass, is updated the same way and shortens the horizon alongside the first::

    μ       <- clip(μ + lr_q · (q − q̄), 0, ν_max)
    H        = clip(round(H_max − κ · (ν + μ)), H_min, H_max)

so the horizon shrinks while more than ``q̄`` of the adjoints are capped and grows back (as far as the contact
dual allows) while fewer are.
"""

from __future__ import annotations

import logging

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torch import nn

__all__ = ["AdaptiveHorizon"]

log = logging.getLogger(__name__)


class AdaptiveHorizon(nn.Module):
    """Dual-variable horizon controller; an ``nn.Module`` so the dual is saved in ``state_dict``.

    Args:
        horizon_min, horizon_max: bounds of the horizon (DiffRL AHAC: 8 and 64).
        contact_threshold: ``C̄``, the per-step contact-force norm budget (500).
        lr: dual learning rate (5e-4).
        steps_per_dual: ``κ``, horizon steps removed per unit of the dual (1.0).
        horizon_init: starting horizon (default ``horizon_max``, i.e. ``ν = 0``).
        world_reduction: ``"mean"`` or ``"max"`` over worlds of the per-step force norms.
        contact_key: key of the per-step contact force in a rollout (the DexMOTS envs write
            ``("object", "contact_force")`` shaped ``[N, 1]``, so a rollout holds it under
            ``("next", "object", "contact_force")``, shaped ``[N, T, 1]``).
        clip_share_target: ``q̄``, the share of capped world-step adjoints above which the horizon shortens
            (``None``: the contact dual alone sets the horizon).
        clip_share_lr: ``lr_q``, dual units per unit of share above or below ``q̄`` (20: a share 10 points
            above the target removes two horizon steps per rollout).

    Example:
        >>> ahac = AdaptiveHorizon(horizon_min=8, horizon_max=64)
        >>> ahac.horizon
        64
        >>> for _ in range(40):
        ...     _ = ahac.update(torch.full((16, ahac.horizon, 1), 1000.0))  # stiff contact: s - C̄ = 500
        >>> ahac.horizon  # ν = 40 · 5e-4 · 500 = 10
        54
    """

    def __init__(
        self,
        horizon_min: int = 8,
        horizon_max: int = 64,
        contact_threshold: float = 500.0,
        lr: float = 5e-4,
        steps_per_dual: float = 1.0,
        horizon_init: int | None = None,
        world_reduction: str = "mean",
        contact_key: NestedKey = ("next", "object", "contact_force"),
        clip_share_target: float | None = None,
        clip_share_lr: float = 20.0,
    ):
        super().__init__()
        if not 0 < horizon_min <= horizon_max:
            raise ValueError(f"need 0 < horizon_min <= horizon_max, got {horizon_min}, {horizon_max}")
        if lr < 0 or steps_per_dual <= 0 or contact_threshold < 0:
            raise ValueError("lr and contact_threshold must be >= 0 and steps_per_dual > 0")
        if world_reduction not in ("mean", "max"):
            raise ValueError(f"world_reduction must be 'mean' or 'max', got {world_reduction!r}")
        if clip_share_target is not None and not 0 <= clip_share_target < 1:
            raise ValueError(f"clip_share_target must lie in [0, 1), got {clip_share_target}")
        if clip_share_lr < 0:
            raise ValueError(f"clip_share_lr must be >= 0, got {clip_share_lr}")
        self.horizon_min, self.horizon_max = int(horizon_min), int(horizon_max)
        self.contact_threshold, self.lr, self.steps_per_dual = float(contact_threshold), float(lr), float(steps_per_dual)
        self.world_reduction, self.contact_key = world_reduction, contact_key
        self.nu_max = (self.horizon_max - self.horizon_min) / self.steps_per_dual
        init = self.horizon_max if horizon_init is None else int(horizon_init)
        if not self.horizon_min <= init <= self.horizon_max:
            raise ValueError(f"horizon_init {init} outside [{self.horizon_min}, {self.horizon_max}]")
        # float64: increments of lr * (s - C̄) can be tiny next to ν
        self.register_buffer("nu", torch.tensor((self.horizon_max - init) / self.steps_per_dual, dtype=torch.float64))
        self.register_buffer("last_contact", torch.tensor(float("nan"), dtype=torch.float64))
        self.register_buffer("num_updates", torch.tensor(0, dtype=torch.int64))
        self.clip_share_target, self.clip_share_lr = clip_share_target, float(clip_share_lr)
        if clip_share_target is not None:  # only then: checkpoints of contact-only runs keep their keys
            self.register_buffer("mu", torch.tensor(0.0, dtype=torch.float64))

    @property
    def horizon(self) -> int:
        """The horizon for the next rollout, ``clip(round(H_max − κ (ν + μ)), H_min, H_max)``."""
        dual = float(self.nu) + (float(self.mu) if self.clip_share_target is not None else 0.0)
        h = round(self.horizon_max - self.steps_per_dual * dual)
        return int(min(max(h, self.horizon_min), self.horizon_max))

    def step_statistic(self, contact_force: torch.Tensor) -> torch.Tensor:
        """Per-step world-reduced contact-force norms ``s_t``, shape ``[T]``, from a ``[N, T]``,
        ``[N, T, 1]`` (norms) or ``[N, T, D]`` (vectors: the norm over ``D`` is taken) tensor."""
        c = contact_force.detach().to(torch.float64)
        if c.dim() == 3:
            c = c.squeeze(-1) if c.shape[-1] == 1 else c.norm(dim=-1)
        elif c.dim() != 2:
            raise ValueError(f"contact force must be [N, T], [N, T, 1] or [N, T, D], got {tuple(contact_force.shape)}")
        c = c.abs()
        finite = torch.isfinite(c)  # a blown-up world must not drive the horizon
        if self.world_reduction == "mean":
            return torch.where(finite, c, torch.zeros_like(c)).sum(0) / finite.sum(0).clamp_min(1)
        return torch.where(finite, c, torch.zeros_like(c)).amax(0)

    @torch.no_grad()
    def update(self, contact_force: torch.Tensor) -> int:
        """One dual step from the contact forces of the last rollout; returns the new :attr:`horizon`."""
        per_step = self.step_statistic(contact_force)
        if per_step.numel() == 0:
            return self.horizon
        s = per_step.mean()
        self.nu.copy_((self.nu + self.lr * (s - self.contact_threshold)).clamp(0.0, self.nu_max))
        self.last_contact.copy_(s)
        self.num_updates += 1
        log.debug("AHAC: contact %.1f (threshold %.1f) -> nu %.4f, horizon %d",
                  float(s), self.contact_threshold, float(self.nu), self.horizon)
        return self.horizon

    @torch.no_grad()
    def update_clip_share(self, share: float) -> int:
        """One step of the gradient-health dual ``μ`` from the share of world-steps whose adjoint was capped in
        the last backward pass; returns the new :attr:`horizon` (unchanged without ``clip_share_target``)."""
        if self.clip_share_target is None or not share == share:  # off, or NaN: no evidence either way
            return self.horizon
        self.mu.copy_((self.mu + self.clip_share_lr * (share - self.clip_share_target)).clamp(0.0, self.nu_max))
        log.debug("AHAC: capped share %.4f (target %.4f) -> mu %.3f, horizon %d",
                  share, self.clip_share_target, float(self.mu), self.horizon)
        return self.horizon

    def update_from_rollout(self, rollout: TensorDictBase) -> int:
        """:meth:`update` with ``rollout[contact_key]`` (batch ``[N, T]``)."""
        return self.update(rollout.get(self.contact_key))

    def stiff_step(self, rollout: TensorDictBase, contact_key: NestedKey | None = None) -> int | None:
        """Index of the first step whose (world-reduced) contact force exceeds ``C̄``, or ``None``."""
        per_step = self.step_statistic(rollout.get(contact_key or self.contact_key))
        stiff = (per_step > self.contact_threshold).nonzero()
        return int(stiff[0]) if stiff.numel() else None

    def truncate_rollout(self, rollout: TensorDictBase, contact_key: NestedKey | None = None) -> TensorDictBase:
        """The prefix of ``rollout`` (batch ``[N, T]``) before the first stiff-contact step, at least
        ``horizon_min`` steps long (or the whole rollout if shorter / no stiff contact).

        The stiff step itself is dropped: its reward depends on the state after the stiff contact. The SHAC
        loss of the prefix then bootstraps with the target critic at the cut, like at any horizon end."""
        t_stiff = self.stiff_step(rollout, contact_key)
        length = rollout.shape[-1]
        if t_stiff is not None:
            length = min(max(t_stiff, self.horizon_min), length)
        return rollout[..., :length]

    def extra_repr(self) -> str:
        text = (f"horizon={self.horizon}, range=[{self.horizon_min}, {self.horizon_max}], "
                f"threshold={self.contact_threshold}, lr={self.lr}, nu={float(self.nu):.4f}")
        if self.clip_share_target is not None:
            text += f", clip_share_target={self.clip_share_target}, mu={float(self.mu):.4f}"
        return text
