"""torchrl's own SAC and PPO training loops (``sota-implementations/sac`` and ``ppo/ppo_mujoco.py``), rebuilt
on a task env: the reference ``dexmots-bench baselines`` times the baselines' loops against.

Each follows the sota script's pieces in order — its environment transforms, its networks, its loss, its
optimisers (one Adam per network, grouped), its replay buffer and its update function, no compilation (the
scripts' CPU default) — with two changes: the env is ``make_env(task, differentiable=False)`` (the task's
worlds batched in one env instead of gym's one world per process) and the sizes that set the cost
(frames per batch, minibatch, update-to-data ratio, epochs, widths) are the baseline's own, so the figures
compare the implementations and not the settings. PPO's ``VecNorm`` (the new API, ``VecNormV2``, which
torchrl makes the default) reduces over the worlds (``reduce_batch_dims``), as one gym env's statistics
would be over its own steps.

:func:`sac_reference` and :func:`ppo_reference` return per-iteration timing rows shaped like the baselines'
``metrics.jsonl`` (``env_steps``, ``updates``, ``collect_cpu_s`` / ``learn_cpu_s`` and their wall twins).
"""

from __future__ import annotations

import time
import warnings

import torch
from tensordict import TensorDict
from tensordict.nn import AddStateIndependentNormalScale, NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
from torchrl.envs import ClipTransform, DoubleToFloat, InitTracker, RewardSum, StepCounter
from torchrl.envs.transforms.vecnorm import VecNormV2
from torchrl.envs.utils import ExplorationType
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss, SACLoss, SoftUpdate, group_optimizers
from torchrl.objectives.value import GAE

from ..envs import make_env

__all__ = ["ppo_reference", "sac_reference"]

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


class _PhaseClock:
    """CPU and wall seconds of one phase of an iteration (``collect`` or ``learn``)."""

    def __init__(self):
        self.cpu, self.wall = time.process_time(), time.perf_counter()

    def lap(self) -> tuple[float, float]:
        cpu, wall = time.process_time(), time.perf_counter()
        lap = (cpu - self.cpu, wall - self.wall)
        self.cpu, self.wall = cpu, wall
        return lap


def _row(env_steps: int, updates: int, collect, learn) -> dict:
    return {"env_steps": env_steps, "updates": updates, "collect_cpu_s": collect[0], "collect_wall_s": collect[1],
            "learn_cpu_s": learn[0], "learn_wall_s": learn[1]}


def _task_env(task: str, num_envs: int, seed: int, transforms):
    env = make_env(task, num_envs=num_envs, differentiable=False, seed=seed)
    with warnings.catch_warnings():  # VecNorm's "experimental for a batched env"
        warnings.simplefilter("ignore", UserWarning)
        for transform in transforms:
            env.append_transform(transform)
        env.observation_spec  # noqa: B018  (built here, where the warning is filtered)
    return env


def _tanh_normal_actor(module, spec, return_log_prob: bool) -> ProbabilisticActor:
    return ProbabilisticActor(
        TensorDictModule(module, in_keys=["observation"], out_keys=["loc", "scale"]), in_keys=["loc", "scale"],
        spec=spec, distribution_class=TanhNormal,
        distribution_kwargs={"low": spec.space.low, "high": spec.space.high, "tanh_loc": False},
        return_log_prob=return_log_prob, default_interaction_type=ExplorationType.RANDOM)


def sac_reference(task: str, algo, iterations: int, num_envs: int, seed: int = 0, transforms=()) -> list[dict]:
    """``iterations`` collector iterations of torchrl's sota SAC on ``task`` with ``algo``'s sizes (the
    ``sac`` section: ``frames_per_batch``, ``init_random_frames``, ``utd_ratio``, ``batch_size``, ``hidden``,
    ``activation``, learning rates, ``gamma``, ``tau``, ``alpha_init``)."""
    torch.manual_seed(seed)
    # utils.apply_env_transforms (no observation normalisation in sota SAC)
    env = _task_env(task, num_envs, seed, [*transforms, InitTracker(), StepCounter(), DoubleToFloat(), RewardSum()])
    spec = env.action_spec_unbatched
    act = ACTIVATIONS[algo.activation]
    actor_net = nn.Sequential(MLP(num_cells=list(algo.hidden), out_features=2 * spec.shape[-1], activation_class=act),
                              NormalParamExtractor(scale_mapping="biased_softplus_1.0", scale_lb=0.1))
    actor = _tanh_normal_actor(actor_net, spec, return_log_prob=False)
    qvalue = ValueOperator(MLP(num_cells=list(algo.hidden), out_features=1, activation_class=act),
                           in_keys=["action", "observation"])
    with torch.no_grad():  # utils.make_sac_agent: lazy layers materialised on a fake tensordict
        td = env.fake_tensordict()
        actor(td)
        qvalue(td)
    loss_module = SACLoss(actor_network=actor, qvalue_network=qvalue, num_qvalue_nets=2, loss_function="l2",
                          delay_actor=False, delay_qvalue=True, alpha_init=algo.alpha_init)
    loss_module.make_value_estimator(gamma=algo.gamma)
    target_net_updater = SoftUpdate(loss_module, eps=1.0 - algo.tau)
    optimizer = group_optimizers(
        torch.optim.Adam(list(loss_module.actor_network_params.flatten_keys().values()), lr=algo.actor_lr),
        torch.optim.Adam(list(loss_module.qvalue_network_params.flatten_keys().values()), lr=algo.critic_lr),
        torch.optim.Adam([loss_module.log_alpha], lr=algo.alpha_lr))
    replay_buffer = TensorDictReplayBuffer(pin_memory=False, prefetch=3,
                                           storage=LazyTensorStorage(int(algo.buffer_size)),
                                           batch_size=algo.batch_size)
    frames_per_batch = int(algo.frames_per_batch)
    init_random_frames = int(algo.init_random_frames)
    collector = Collector(env, actor, init_random_frames=init_random_frames, frames_per_batch=frames_per_batch,
                          total_frames=iterations * frames_per_batch, device="cpu")

    def update(sampled_tensordict):
        loss_td = loss_module(sampled_tensordict)
        (loss_td["loss_actor"] + loss_td["loss_qvalue"] + loss_td["loss_alpha"]).sum().backward()
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        target_net_updater.step()
        return loss_td.detach()

    num_updates = int(frames_per_batch * algo.utd_ratio)
    rows, collected_frames, clock = [], 0, _PhaseClock()
    for tensordict in collector:
        collect = clock.lap()
        collector.update_policy_weights_()
        replay_buffer.extend(tensordict.reshape(-1))
        collected_frames += tensordict.numel()
        updates = 0
        if collected_frames >= init_random_frames:
            losses = TensorDict(batch_size=[num_updates])
            for i in range(num_updates):
                losses[i] = update(replay_buffer.sample()).clone().select("loss_actor", "loss_qvalue", "loss_alpha")
            updates = num_updates
            losses.mean()
        episode_end = tensordict["next", "done"]
        tensordict["next", "episode_reward"][episode_end]  # noqa: B018  (sota's logged statistics)
        rows.append(_row(tensordict.numel(), updates, collect, clock.lap()))
    collector.shutdown()
    return rows


def ppo_reference(task: str, algo, iterations: int, num_envs: int, seed: int = 0, transforms=()) -> list[dict]:
    """``iterations`` collector iterations of torchrl's sota PPO (``ppo_mujoco.py``) on ``task`` with ``algo``'s
    sizes (``frames_per_batch``, ``minibatch_size``, ``epochs``, ``hidden``, ``activation``, ``lr``, ``gamma``,
    ``lmbda``, ``clip_epsilon``, ``entropy_coeff``, ``critic_coeff``, ``loss_critic_type``); ``transforms``:
    a method's own observation and reward before the normalisation (PGDM's)."""
    torch.manual_seed(seed)
    # utils_mujoco._add_ppo_transforms
    env = _task_env(task, num_envs, seed, [*transforms, VecNormV2(in_keys=["observation"], decay=0.99999, eps=1e-2,
                                                               reduce_batch_dims=True),
                                           ClipTransform(in_keys=["observation"], low=-10, high=10), RewardSum(),
                                           StepCounter()])
    obs_dim, spec = env.observation_spec["observation"].shape[-1], env.action_spec_unbatched
    act = ACTIVATIONS[algo.activation]
    # utils_mujoco.make_ppo_models_state
    policy_mlp = MLP(in_features=obs_dim, activation_class=act, out_features=spec.shape[-1],
                     num_cells=list(algo.hidden))
    value_mlp = MLP(in_features=obs_dim, activation_class=act, out_features=1, num_cells=list(algo.hidden))
    for net, gain in ((policy_mlp, 1.0), (value_mlp, 0.01)):
        for layer in net.modules():
            if isinstance(layer, nn.Linear):
                nn.init.orthogonal_(layer.weight, gain)
                layer.bias.data.zero_()
    actor = _tanh_normal_actor(nn.Sequential(policy_mlp, AddStateIndependentNormalScale(spec.shape[-1],
                                                                                       scale_lb=1e-8)),
                               spec, return_log_prob=True)
    critic = ValueOperator(value_mlp, in_keys=["observation"])
    frames_per_batch = int(algo.frames_per_batch)
    collector = Collector(create_env_fn=env, policy=actor, frames_per_batch=frames_per_batch,
                          total_frames=iterations * frames_per_batch, device="cpu", max_frames_per_traj=-1)
    data_buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(frames_per_batch),
                                         sampler=SamplerWithoutReplacement(), batch_size=int(algo.minibatch_size))
    adv_module = GAE(gamma=algo.gamma, lmbda=algo.lmbda, value_network=critic, average_gae=False, vectorized=True)
    loss_module = ClipPPOLoss(actor_network=actor, critic_network=critic, clip_epsilon=algo.clip_epsilon,
                              loss_critic_type=algo.loss_critic_type, entropy_coeff=algo.entropy_coeff,
                              critic_coeff=algo.critic_coeff, normalize_advantage=True)
    lr = torch.tensor(float(algo.lr))
    optim = group_optimizers(torch.optim.Adam(actor.parameters(), lr=lr.clone(), eps=1e-5),
                             torch.optim.Adam(critic.parameters(), lr=lr.clone(), eps=1e-5))
    num_mini_batches = frames_per_batch // int(algo.minibatch_size)
    total_network_updates = iterations * int(algo.epochs) * num_mini_batches

    def update(batch, num_network_updates):
        optim.zero_grad(set_to_none=True)
        alpha = (1 - (num_network_updates / total_network_updates)).clamp_min(0.0)
        for group in optim.param_groups:
            group["lr"] = lr * alpha
        loss = loss_module(batch)
        (loss["loss_critic"] + loss["loss_objective"] + loss["loss_entropy"]).backward()
        optim.step()
        return loss.detach().set("alpha", alpha), num_network_updates + 1

    num_network_updates = torch.zeros((), dtype=torch.int64)
    losses = TensorDict(batch_size=[int(algo.epochs), num_mini_batches])
    rows, clock = [], _PhaseClock()
    for data in collector:
        collect = clock.lap()
        updates = 0
        for j in range(int(algo.epochs)):
            with torch.no_grad():
                data = adv_module(data)
            data_buffer.extend(data.reshape(-1))
            for k, batch in enumerate(data_buffer):
                loss, num_network_updates = update(batch, num_network_updates)
                losses[j, k] = loss.select("loss_critic", "loss_entropy", "loss_objective")
                updates += 1
        losses.apply(lambda x: x.float().mean(), batch_size=[])
        collector.update_policy_weights_()
        rows.append(_row(data.numel(), updates, collect, clock.lap()))
    collector.shutdown()
    return rows
