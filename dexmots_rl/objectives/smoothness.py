"""A policy-smoothness regulariser (CAPS, Mysore et al. 2021) as a torchrl ``LossModule``.

Why it is here: on screw_claw the AHAC runs that failed had learnt policies whose mean action jumps
between consecutive steps (final-policy temporal loss 0.9-1.7 against 0.1-0.4 in the runs that learnt),
and a closed loop like that amplifies the gradient through the simulator over the horizon (the clipped
adjoint share rose from ~0.1 % to 3-6 %). Penalising the jumps directly keeps the policy out of that
regime without touching the simulator's gradient (docs/devnotes.md, training).

Both terms read detached observations, so they act on the policy's weights only:

* temporal: ``mean_t ||tanh(loc(o_{t+1})) - tanh(loc(o_t))||^2`` over consecutive steps of a rollout,
  pairs that cross an episode boundary (``("next", "done")`` at ``t``) left out;
* spatial: ``mean ||tanh(loc(o + sigma * s * eps)) - tanh(loc(o))||^2`` with ``eps ~ N(0, I)`` and ``s``
  each observation feature's standard deviation over the batch (so ``sigma`` is unit-free).

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> from tensordict.nn import TensorDictModule
    >>> net = TensorDictModule(torch.nn.Linear(3, 2), in_keys=["observation"], out_keys=["loc"])
    >>> loss = PolicySmoothnessLoss(net, spatial_sigma=0.05)
    >>> td = TensorDict(observation=torch.randn(4, 8, 3), next=TensorDict(done=torch.zeros(4, 8, 1, dtype=torch.bool),
    ...                 batch_size=[4, 8]), batch_size=[4, 8])
    >>> out = loss(td)
    >>> sorted(out.keys())
    ['loss_smooth_spatial', 'loss_smooth_temporal']
    >>> (out["loss_smooth_temporal"] + out["loss_smooth_spatial"]).backward()
    >>> net.module.weight.grad.abs().sum() > 0
    tensor(True)
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule

from .shac import _finite_rows, _tuple

__all__ = ["PolicySmoothnessLoss"]


class PolicySmoothnessLoss(LossModule):
    """Temporal and spatial smoothness of a policy's mean action (module doc).

    Args:
        actor_network: a module writing the (pre-tanh) mean action ``loc`` from ``observation`` — for the
            networks of :func:`dexmots_rl.algorithms.networks.make_networks`, ``actor[0]``.
        spatial_sigma: the observation perturbation of the spatial term, in units of each feature's batch
            standard deviation (0 turns the term off).

    The input is a rollout with time as its last batch dimension (``[*B, T]``, torchrl's layout). Returns
    ``loss_smooth_temporal`` and ``loss_smooth_spatial`` (unweighted: the caller weights them).
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys (``loss.set_keys(observation="pixels_state")``).

        Attributes:
            observation: the policy's input. Defaults to ``"observation"``.
            loc: where ``actor_network`` writes its pre-squash mean action. Defaults to ``"loc"``.
            done: read under ``"next"``: a pair ``(t, t+1)`` with ``done`` at ``t`` is left out.
        """

        observation: NestedKey = "observation"
        loc: NestedKey = "loc"
        done: NestedKey = "done"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys

    actor_network: TensorDictModule
    actor_network_params: TensorDictBase
    target_actor_network_params: TensorDictBase

    def __init__(self, actor_network: TensorDictModule, *, spatial_sigma: float = 0.05):
        super().__init__()
        if not spatial_sigma >= 0:
            raise ValueError(f"spatial_sigma must be >= 0, got {spatial_sigma!r}")
        self.convert_to_functional(actor_network, "actor_network")
        self.spatial_sigma = float(spatial_sigma)

    @property
    def in_keys(self) -> list[NestedKey]:
        k = self.tensor_keys
        return [k.observation, ("next", *_tuple(k.done))]

    @property
    def out_keys(self) -> list[str]:
        return ["loss_smooth_temporal", "loss_smooth_spatial"]

    def _action(self, obs: torch.Tensor) -> torch.Tensor:
        k = self.tensor_keys
        td = TensorDict({k.observation: obs}, batch_size=obs.shape[:-1])
        with self.actor_network_params.to_module(self.actor_network):
            return torch.tanh(self.actor_network(td).get(k.loc))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        k = self.tensor_keys
        if tensordict.ndim < 1:
            raise ValueError("the rollout needs a time dimension as its last batch dimension ([*B, T])")
        obs, bad = _finite_rows(tensordict.get(k.observation).detach(), tensordict.batch_size)
        finite = ~bad  # a world-step that blew up is left out
        action = self._action(obs)
        done = tensordict.get(("next", k.done)).reshape(finite.shape).bool()
        keep = (~done[..., :-1] & finite[..., :-1] & finite[..., 1:]).to(action.dtype)
        jump = (action[..., 1:, :] - action[..., :-1, :]).square().sum(-1)
        temporal = (jump * keep).sum() / keep.sum().clamp_min(1.0)
        spatial = torch.zeros((), dtype=action.dtype, device=action.device)
        if self.spatial_sigma > 0:
            flat = obs[finite]
            scale = flat.std(0) if flat.shape[0] > 1 else torch.ones_like(obs[..., 0, :])
            noisy = self._action(obs + self.spatial_sigma * scale * torch.randn_like(obs))
            w = finite.to(action.dtype)
            spatial = ((noisy - action).square().sum(-1) * w).sum() / w.sum().clamp_min(1.0)
        return TensorDict({"loss_smooth_temporal": temporal, "loss_smooth_spatial": spatial}, batch_size=[])
