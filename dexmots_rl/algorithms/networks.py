"""Actor and critic networks for SHAC/AHAC, with a running observation normaliser.

The normaliser is a module with buffers (saved in checkpoints) shared by actor and critic. It is
*frozen* while a differentiable rollout is made (its statistics are constants inside the graph) and
updated from the finished rollout, outside the graph (DiffRL's ``obs_rms``).

Example:
    >>> import torch
    >>> actor, critic, norm = make_networks(obs_dim=6, action_dim=2, hidden=(32, 32))
    >>> td = torch.zeros(4, 6)
    >>> norm.update(torch.randn(100, 6))
    >>> from tensordict import TensorDict
    >>> out = critic(TensorDict(observation=td, batch_size=[4]))
    >>> out["state_value"].shape
    torch.Size([4, 1])
"""

from __future__ import annotations

import torch
from tensordict.nn import AddStateIndependentNormalScale, TensorDictModule
from torch import nn
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

__all__ = ["RunningNorm", "make_networks"]


class RunningNorm(nn.Module):
    """``(x - mean) / sqrt(var + eps)`` clipped to ±``clip``, with statistics updated by :meth:`update`."""

    def __init__(self, dim: int, eps: float = 1e-5, clip: float = 5.0):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(eps, dtype=torch.float64))
        self.eps, self.clip = eps, clip

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Merge the batch statistics of ``x`` [..., dim] (Chan et al.'s parallel variance); non-finite rows skipped."""
        x = x.detach().reshape(-1, self.mean.shape[0]).to(torch.float64)
        x = x[torch.isfinite(x).all(-1)]
        if x.shape[0] == 0:
            return
        b_mean, b_var, b_count = x.mean(0), x.var(0, unbiased=False), x.shape[0]
        delta = b_mean - self.mean
        total = self.count + b_count
        self.mean += delta * b_count / total
        self.var.copy_((self.var * self.count + b_var * b_count + delta.square() * self.count * b_count / total) / total)
        self.count.copy_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mean, std = self.mean.to(x.dtype), torch.sqrt(self.var + self.eps).to(x.dtype)
        return ((x - mean) / std).clamp(-self.clip, self.clip)


def _mlp(in_features: int, out_features: int, hidden, layer_norm: bool) -> MLP:
    norm = {"norm_class": nn.LayerNorm, "norm_kwargs": [{"normalized_shape": h} for h in hidden]} if layer_norm else {}
    return MLP(in_features=in_features, out_features=out_features, num_cells=list(hidden), activation_class=nn.ELU,
               **norm)


def make_networks(obs_dim: int, action_dim: int, hidden=(256, 128), init_log_std: float = -1.0,
                  obs_key="observation", layer_norm: bool = True, critic_hidden=None, init_action=None):
    """``(actor, critic, norm)``: a ``ProbabilisticActor`` (TanhNormal, state-independent scale) and a
    ``ValueOperator``, both reading ``obs_key`` through the shared :class:`RunningNorm`. ``hidden`` are the
    actor's widths, and the critic's unless ``critic_hidden`` is given.

    ``layer_norm`` puts a LayerNorm after every hidden layer, as DiffRL's SHAC networks do: without it the
    claw's critic diverged (TD targets of +-6e3 for returns below 1.3e2, docs/devnotes.md, training).

    ``init_action`` (``[action_dim]``, each in (-1, 1), or ``None``: 0) is the initial policy's mean action:
    the output layer's bias starts at its ``atanh`` (e.g. a ``vi`` policy that starts stiff,
    :meth:`~dexmots_rl.envs.actions.ActionMap.mean_actions`)."""
    norm = RunningNorm(obs_dim)
    body = _mlp(obs_dim, action_dim, hidden, layer_norm)
    if init_action is not None:
        init_action = torch.as_tensor(init_action, dtype=torch.float32)
        if init_action.shape != (action_dim,) or not bool((init_action.abs() < 1).all()):
            raise ValueError(f"init_action must be {action_dim} values in (-1, 1), got {init_action.tolist()}")
        with torch.no_grad():
            body[-1].bias.copy_(torch.atanh(init_action))
    # the scale parameter is a log-std (exp mapping), as in SHAC's Gaussian actor
    loc_scale = nn.Sequential(norm, body, AddStateIndependentNormalScale(action_dim, scale_lb=1e-4,
                                                                         init_value=init_log_std))
    actor = ProbabilisticActor(TensorDictModule(loc_scale, in_keys=[obs_key], out_keys=["loc", "scale"]),
                               in_keys=["loc", "scale"], distribution_class=TanhNormal,
                               distribution_kwargs={"low": -1.0, "high": 1.0}, return_log_prob=False)
    value = nn.Sequential(norm, _mlp(obs_dim, 1, hidden if critic_hidden is None else critic_hidden, layer_norm))
    critic = ValueOperator(value, in_keys=[obs_key])
    return actor, critic, norm
