"""SHAC (Short-Horizon Actor-Critic, Xu et al. 2022) as a torchrl :class:`~torchrl.objectives.LossModule`.

The actor is trained by back-propagating the discounted return of a short differentiable rollout (plus a
target-critic bootstrap) through the simulator; the critic regresses TD(lambda) targets of the detached
rollout. Nothing here knows about DexMOTS: any torchrl env whose step is differentiable works.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torchrl.envs.utils import step_mdp
from torchrl.objectives import LossModule
from torchrl.objectives.utils import ValueEstimators, dispatch_value_estimator, distance_loss

__all__ = ["SHACLoss", "next_rollout_start"]

log = logging.getLogger(__name__)


def _finite(x: torch.Tensor) -> torch.Tensor:
    # One world that blew up must not poison the batch: its non-finite entries count as 0 (and the
    # backward of nan_to_num gives those entries zero gradient).
    return torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0)


def _finite_rows(x: torch.Tensor, batch_shape) -> tuple[torch.Tensor, torch.Tensor]:
    """``x`` with its non-finite entries zeroed, and [*batch_shape] flags of the rows that had any."""
    ok = torch.isfinite(x)
    return torch.where(ok, x, torch.zeros_like(x)), ~ok.reshape(*batch_shape, -1).all(-1)


def _zero_rows(value: torch.Tensor, bad: torch.Tensor | None) -> torch.Tensor:
    """``value`` with the rows flagged in ``bad`` set to 0 (by selection: their gradient is 0, not NaN)."""
    if bad is None:
        return value
    bad = bad.reshape(*bad.shape, *([1] * (value.dim() - bad.dim())))
    return torch.where(bad, torch.zeros_like(value), value)


def next_rollout_start(env, rollout: TensorDictBase) -> TensorDictBase:
    """The root TensorDict to start the next rollout from: the last step's ``"next"`` data, with the worlds
    that were done at that step reset, detached so that gradients stop at the rollout boundary (SHAC
    truncates the graph every ``H`` steps)."""
    return env.maybe_reset(step_mdp(rollout[..., -1].detach()))


class SHACLoss(LossModule):
    r"""SHAC actor and critic losses on a differentiable rollout.

    **Actor loss** (DiffRL ``shac.py`` accounting). Per world, with ``k`` the steps since the last episode
    end inside the rollout (``k`` restarts at 0 after a done step)::

        loss_actor = -1/(H N) * sum_worlds [ sum_t gamma^k_t r_t
                                             + sum_{t: done_t or t = H-1} gamma^(k_t+1) V'(s'_t) (1 - terminated_t) ]

    ``V'`` is the **target** critic and ``s'_t = ("next", obs)`` of step ``t``: at a truncation that is the
    pre-reset observation (torchrl's rollout resets done worlds in the *root* of step ``t+1`` even with
    ``auto_reset=False``, but keeps ``("next", ...)`` of step ``t`` pre-reset), at a termination the
    bootstrap is 0, and after the last step it bootstraps the state the horizon stopped in. Gradients flow
    to the actor through the rewards and through ``s'_t`` (the target critic is a function of the state),
    never into critic parameters: the target parameters are buffers. Rewards and values are passed through
    ``nan_to_num`` so a blown-up world contributes 0.

    **Critic loss**: ``mean((V(s_t) - G_t)^2)`` on the *detached* rollout, where ``G_t`` are TD(lambda)
    targets from torchrl's value estimator fed with ``V'(s'_t)`` (``G_t = r_t + gamma[(1-lambda) V'(s'_t) +
    lambda G_{t+1}]``, cut at done steps, ``V' = 0`` after a termination). :meth:`critic_targets` computes
    them once (``"value_target"``) so a trainer can iterate :meth:`critic_loss` over minibatches.

    The target critic moves only through a torchrl updater (:class:`~torchrl.objectives.SoftUpdate` /
    :class:`~torchrl.objectives.HardUpdate`). DiffRL's ``target_critic_alpha`` is the fraction of the old
    target that is *kept*: ``alpha = 0.2`` is ``SoftUpdate(loss, eps=0.2)`` = ``SoftUpdate(loss, tau=0.8)``
    (torchrl warns for ``eps < 0.5``; with SHAC's values that warning is expected).

    ``LossModule.forward`` (and :meth:`actor_loss` / :meth:`critic_loss`) run under deterministic
    exploration; that does not matter here because the actor loss uses the rewards the rollout already
    computed with sampled (``rsample``) actions: make the rollout under
    ``set_exploration_type(ExplorationType.RANDOM)``.

    Args:
        actor_network: the policy used to make the rollout (e.g. a ``ProbabilisticActor``); registered so
            that its parameters are part of the loss (optimisers, checkpoints).
        critic_network: state-value operator (e.g. ``ValueOperator``) writing ``"state_value"``.
        gamma, lmbda: discount and TD(lambda) parameter (DiffRL defaults 0.99, 0.95).
        loss_critic_type: ``"l2"`` (default, the DiffRL MSE), ``"l1"`` or ``"smooth_l1"``.
        reduction: reduction of the critic loss (``"mean"``).

    Example (a differentiable 1-D integrator written inline; any differentiable torchrl env works):

        >>> import torch
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import NormalParamExtractor, TensorDictModule
        >>> from torchrl.data import Bounded, Composite, Unbounded
        >>> from torchrl.envs import EnvBase
        >>> from torchrl.envs.utils import ExplorationType, set_exploration_type
        >>> from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
        >>> from torchrl.objectives import SoftUpdate
        >>> from dexmots_rl.objectives import SHACLoss, next_rollout_start
        >>> class Integrator(EnvBase):  # x' = x + 0.1 a, reward -x'^2, differentiable end to end
        ...     def __init__(self, n):
        ...         super().__init__(batch_size=[n])
        ...         self.observation_spec = Composite(observation=Unbounded((n, 1)), shape=(n,))
        ...         self.action_spec = Bounded(-1.0, 1.0, (n, 1))
        ...         self.reward_spec = Unbounded((n, 1))
        ...     def _reset(self, td=None, **kwargs):
        ...         return TensorDict(observation=torch.randn(*self.batch_size, 1), batch_size=self.batch_size)
        ...     def _step(self, td):
        ...         x = td["observation"] + 0.1 * td["action"]
        ...         done = torch.zeros_like(x, dtype=torch.bool)
        ...         return TensorDict(observation=x, reward=-x.pow(2), done=done, terminated=done,
        ...                           batch_size=self.batch_size)
        ...     def _set_seed(self, seed):
        ...         torch.manual_seed(seed)
        >>> env = Integrator(16)
        >>> net = torch.nn.Sequential(torch.nn.Linear(1, 2), NormalParamExtractor())
        >>> actor = ProbabilisticActor(TensorDictModule(net, ["observation"], ["loc", "scale"]),
        ...                            in_keys=["loc", "scale"], distribution_class=TanhNormal)
        >>> critic = ValueOperator(torch.nn.Linear(1, 1), in_keys=["observation"])
        >>> loss = SHACLoss(actor_network=actor, critic_network=critic, gamma=0.99, lmbda=0.95)
        >>> updater = SoftUpdate(loss, tau=0.8)  # DiffRL target_critic_alpha = 0.2
        >>> actor_opt = torch.optim.Adam(actor.parameters(), lr=1e-2)
        >>> critic_opt = torch.optim.Adam(critic.parameters(), lr=1e-2)
        >>> td = env.reset()
        >>> for _ in range(3):
        ...     with set_exploration_type(ExplorationType.RANDOM):  # rsample: reparameterised actions
        ...         rollout = env.rollout(8, actor, auto_reset=False, break_when_any_done=False, tensordict=td)
        ...     out = loss(rollout)  # TensorDict with "loss_actor" and "loss_critic"
        ...     actor_opt.zero_grad()
        ...     out["loss_actor"].backward()  # through the rollout, into the actor only
        ...     actor_opt.step()
        ...     data = loss.critic_targets(rollout).reshape(-1)  # detached copy + "value_target"
        ...     for _ in range(4):  # critic iterations over shuffled minibatches
        ...         for batch in data[torch.randperm(data.numel())].split(32):
        ...             critic_opt.zero_grad()
        ...             loss.critic_loss(batch).backward()
        ...             critic_opt.step()
        ...     updater.step()  # polyak-average the target critic
        ...     td = next_rollout_start(env, rollout)  # continue the episodes, graph cut
        >>> sorted(out.keys())
        ['loss_actor', 'loss_critic']
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys (``loss.set_keys(reward=("next_level", "reward"))``).

        Attributes:
            action: the action key (listed in :attr:`in_keys` only; the actor loss reads rewards).
            reward / done / terminated: read under ``"next"``; ``terminated`` defaults to ``done`` if absent.
            value: where the critic writes its estimate. Defaults to ``"state_value"``.
            value_target: where :meth:`critic_targets` writes the TD(lambda) targets.
        """

        action: NestedKey = "action"
        reward: NestedKey = "reward"
        done: NestedKey = "done"
        terminated: NestedKey = "terminated"
        value: NestedKey = "state_value"
        value_target: NestedKey = "value_target"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys
    default_value_estimator = ValueEstimators.TDLambda
    SUPPORTED_VALUE_ESTIMATORS = (ValueEstimators.TD0, ValueEstimators.TD1, ValueEstimators.TDLambda)

    actor_network: TensorDictModule
    actor_network_params: TensorDictBase
    target_actor_network_params: TensorDictBase
    critic_network: TensorDictModule
    critic_network_params: TensorDictBase
    target_critic_network_params: TensorDictBase

    def __init__(
        self,
        actor_network: TensorDictModule,
        critic_network: TensorDictModule,
        *,
        gamma: float = 0.99,
        lmbda: float = 0.95,
        loss_critic_type: str = "l2",
        reduction: str = "mean",
    ):
        super().__init__()
        self.convert_to_functional(actor_network, "actor_network")
        self.convert_to_functional(critic_network, "critic_network", create_target_params=True)
        self.register_buffer("gamma", torch.tensor(float(gamma)))
        self.register_buffer("lmbda", torch.tensor(float(lmbda)))
        self.loss_critic_type = loss_critic_type
        self.reduction = reduction

    # --------------------------------------------------------------------------------------- keys
    @property
    def in_keys(self) -> list[NestedKey]:
        keys = self.tensor_keys
        critic_in = list(self.critic_network.in_keys)
        return [*critic_in, *(("next", *_tuple(k)) for k in critic_in), keys.action,
                ("next", *_tuple(keys.reward)), ("next", *_tuple(keys.done)), ("next", *_tuple(keys.terminated))]

    @property
    def out_keys(self) -> list[str]:
        return ["loss_actor", "loss_critic"]

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        if self._value_estimator is not None:
            k = self.tensor_keys
            self._value_estimator.set_keys(value=k.value, value_target=k.value_target, reward=k.reward,
                                           done=k.done, terminated=k.terminated)

    def make_value_estimator(self, value_type: ValueEstimators | None = None, **hyperparams) -> SHACLoss:
        """Build the critic-target estimator (default TD(lambda), gamma/lmbda from the loss).

        SHAC uses one discount for both halves, so a ``gamma`` (``lmbda``) given here also becomes the
        actor-loss discount (the loss's TD(lambda) parameter). Supported: TD0, TD1, TDLambda."""
        value_type, hp = self._prepare_value_estimator_kwargs(value_type, **hyperparams)
        if value_type is None:  # an estimator instance or class was given: LossModule handled it
            return self
        if "gamma" in hyperparams:
            self.gamma.fill_(float(hyperparams["gamma"]))
        if "lmbda" in hyperparams:
            self.lmbda.fill_(float(hyperparams["lmbda"]))
        hp["gamma"] = float(self.gamma)  # a python float: the estimators build their own buffers
        if value_type == ValueEstimators.TDLambda:
            hp["lmbda"] = float(self.lmbda)
        hp.setdefault("device", self.gamma.device)
        k = self.tensor_keys
        dispatch_value_estimator(
            self, value_type, supported=self.SUPPORTED_VALUE_ESTIMATORS,
            tensor_keys={"value": k.value, "value_target": k.value_target, "reward": k.reward,
                         "done": k.done, "terminated": k.terminated},
            **hp,
        )
        return self

    # ------------------------------------------------------------------------------------ helpers
    def _value(self, td: TensorDictBase, params: TensorDictBase) -> torch.Tensor:
        """The critic's value of ``td`` with ``params``, without writing into ``td``.

        A world whose input is not finite gets value 0 and a zero (not NaN) gradient: its entries are
        replaced *before* the network (``torch.where``), since NaN through an MLP's backward stays NaN."""
        inputs = td.select(*self.critic_network.in_keys, strict=True).copy()
        bad = None
        for key, x in inputs.items(True, True):
            if x.is_floating_point():
                x, row_bad = _finite_rows(x, td.batch_size)
                bad = row_bad if bad is None else bad | row_bad
                inputs.set(key, x)
        with params.to_module(self.critic_network):
            value = _finite(self.critic_network(inputs).get(self.tensor_keys.value))
        return _zero_rows(value, bad)

    def _next_entries(self, td: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        k = self.tensor_keys
        reward = td.get(("next", *_tuple(k.reward)))
        done = td.get(("next", *_tuple(k.done)))
        terminated = td.get(("next", *_tuple(k.terminated)), None)
        if terminated is None:
            terminated = done
        return reward, done.bool(), terminated.bool()

    # ------------------------------------------------------------------------------------- losses
    def actor_loss(self, tensordict: TensorDictBase) -> torch.Tensor:
        """``-(discounted horizon returns + target-critic bootstraps) / (H N)`` (see the class doc).

        ``tensordict`` is the differentiable rollout, batch ``[*B, H]`` with time last (torchrl's layout)."""
        names = tensordict.names if tensordict.ndim else []
        if tensordict.ndim < 1 or ("time" in names and names.index("time") != tensordict.ndim - 1):
            raise ValueError(f"the rollout needs time as its last batch dimension ([*B, H]), got names {names}")
        reward, done, terminated = self._next_entries(tensordict)
        # V'(s'_t) for every step; the target params are buffers, so only the state carries gradient
        next_value = self._value(tensordict.get("next"), self.target_critic_network_params).reshape(reward.shape)
        reward = _finite(reward)
        t_dim = tensordict.ndim - 1
        horizon = reward.shape[t_dim]
        gamma = self.gamma.to(reward.dtype)
        with torch.no_grad():
            # gamma^k_t with k restarting after every done step; an episode segment ends at a done step or
            # at the end of the horizon, and bootstraps there unless it terminated
            discount = torch.empty_like(reward)
            running = torch.ones_like(reward.select(t_dim, 0))
            for t in range(horizon):
                discount.select(t_dim, t).copy_(running)
                running = torch.where(done.select(t_dim, t), torch.ones_like(running), running * gamma)
            segment_end = done.clone()
            segment_end.select(t_dim, horizon - 1).fill_(True)
            bootstrap = segment_end & ~terminated
        returns = discount * reward + torch.where(bootstrap, discount * gamma * next_value,
                                                  torch.zeros_like(next_value))
        return -returns.sum() / tensordict.numel()

    @torch.no_grad()
    def critic_targets(self, tensordict: TensorDictBase) -> TensorDictBase:
        """A detached copy of the rollout with the TD(lambda) targets under ``tensor_keys.value_target``.

        Computed once per rollout with the **target** critic on ``("next", obs)`` (pre-reset at truncations)
        by torchrl's value estimator; iterate :meth:`critic_loss` over minibatches of the result."""
        data = tensordict.detach()
        reward = _finite(self._next_entries(data)[0])
        # non-finite rewards would spread back in time through the lambda recursion: zero them in the copy
        data.set(("next", *_tuple(self.tensor_keys.reward)), reward)
        next_value = self._value(data.get("next"), self.target_critic_network_params).reshape(reward.shape)
        target = self.value_estimator.value_estimate(data, next_value=next_value)
        data.set(self.tensor_keys.value_target, _finite(target))
        return data

    def critic_loss(self, tensordict: TensorDictBase) -> torch.Tensor:
        """Regression of the critic onto ``tensor_keys.value_target`` (see :meth:`critic_targets`).

        A rollout without the targets gets them computed here (as torchrl's losses do); a trainer that
        iterates minibatches calls :meth:`critic_targets` once instead, since targets need whole
        trajectories. Inputs and targets are detached: no gradient reaches the actor or the rollout."""
        target = tensordict.get(self.tensor_keys.value_target, None)
        if target is None:
            tensordict = self.critic_targets(tensordict)
            target = tensordict.get(self.tensor_keys.value_target)
        value = self._value(tensordict.detach(), self.critic_network_params)
        loss = distance_loss(target.detach().reshape(value.shape), value, loss_function=self.loss_critic_type)
        return self._reduce_loss(loss, tensordict)

    def fit_critic(self, data: TensorDictBase, optimizer: torch.optim.Optimizer, iterations: int,
                   minibatches: int, on_gradients=None) -> torch.Tensor:
        """Regress the critic onto ``data``'s targets: ``iterations`` passes, each over ``data`` shuffled by
        ``torch.randperm`` and split into ``minibatches`` (plus a remainder), one ``optimizer`` step per
        minibatch; ``on_gradients()`` runs between backward and step (e.g. averaging across ranks).
        Returns the minibatch losses [steps].

        ``data``: flat [N] output of :meth:`critic_targets`. The result is the same as looping
        :meth:`critic_loss` over ``data[torch.randperm(N)].split(N // minibatches)`` (tested), but the
        critic's inputs are extracted and made finite once, not per minibatch: on the claw's 64 x 48-step
        rollouts the loop was the largest part of an iteration (200 of 540 ms) and this takes ~80 ms."""
        if data.ndim != 1:
            raise ValueError(f"fit_critic needs a flat batch (data.reshape(-1)), got batch size {data.batch_size}")
        keys = list(self.critic_network.in_keys)
        inputs = [data.get(k).detach() for k in keys]
        bad = torch.zeros(data.numel(), dtype=torch.bool, device=data.device)
        for i, x in enumerate(inputs):
            if x.is_floating_point():
                inputs[i], row_bad = _finite_rows(x, data.batch_size)
                bad |= row_bad
        target = data.get(self.tensor_keys.value_target).detach()
        out_index = list(self.critic_network.out_keys).index(self.tensor_keys.value)
        module, n = self.critic_network.module, data.numel()
        batch_size = max(1, n // minibatches)
        losses = []
        with self.critic_network_params.to_module(self.critic_network):
            for _ in range(iterations):
                for idx in torch.randperm(n, device=data.device).split(batch_size):
                    optimizer.zero_grad()
                    value = module(*(x[idx] for x in inputs))
                    if isinstance(value, tuple):
                        value = value[out_index]
                    value = _zero_rows(_finite(value), bad[idx])
                    loss = distance_loss(target[idx].reshape(value.shape), value, loss_function=self.loss_critic_type)
                    loss = self._reduce_loss(loss, None)
                    loss.backward()
                    if on_gradients is not None:
                        on_gradients()
                    optimizer.step()
                    losses.append(loss.detach())
        return torch.stack(losses) if losses else torch.zeros(0)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """``"loss_actor"`` on the differentiable rollout and ``"loss_critic"`` on its detached copy.

        Targets already present under ``tensor_keys.value_target`` are reused, otherwise computed."""
        loss_actor = self.actor_loss(tensordict)
        if self.tensor_keys.value_target in tensordict.keys(True):
            data = tensordict.detach()
        else:
            data = self.critic_targets(tensordict)
        loss_critic = self.critic_loss(data)
        if not (torch.isfinite(loss_actor.detach()) and torch.isfinite(loss_critic.detach())):
            log.warning("SHACLoss: non-finite loss (actor %s, critic %s)", float(loss_actor), float(loss_critic))
        return TensorDict({"loss_actor": loss_actor, "loss_critic": loss_critic}, batch_size=[])


def _tuple(key: NestedKey) -> tuple[str, ...]:
    return (key,) if isinstance(key, str) else tuple(key)
