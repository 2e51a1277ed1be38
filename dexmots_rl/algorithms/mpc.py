"""MPC baseline (``dexmots-train algo=mpc``): predictive sampling + gradient refinement through the simulator.

    dexmots-train algo=mpc                                            # screw_claw, 100 evaluation episodes
    dexmots-train algo=mpc algo.candidates=64 algo.horizon=30 algo.refine_steps=0   # pure predictive sampling

Nothing is learnt: the planner acts directly in the evaluation episodes of :func:`.evaluation.evaluate_policy`
(the same worlds, seed and success definition as every trained method). At every control step, for all
evaluation worlds at once:

1. **warm start** — the previous plan (``knots`` action knots over ``horizon`` env steps, zero-order hold or
   linear interpolation between them) is shifted one step forward in time; a world at the start of an episode
   (``("task", "step") == 0``) starts from ``initial_plan`` instead;
2. **sample** — candidate 0 is that nominal plan, candidates 1..K-1 add Gaussian noise of
   ``noise × ½(high − low)`` on every knot, clamped to the action bounds;
3. **roll out** — each world's state (its ``"sim"``, ``"task"`` and ``"info"`` entries) is cloned into K
   worlds of a planning env of N·K worlds, and all candidates run ``horizon`` steps in one batched rollout;
   the best candidate per world wins (the nominal competes, so the plan never gets worse under the model);
4. **refine** — ``refine_steps`` Adam (or SGD) steps on the winner's knots, with the gradient of its return
   backpropagated through a differentiable planning env of N worlds; a refined plan replaces the sampled one
   only where its re-evaluated return is at least as high;
5. **act** — the plan's first action goes to the evaluation env.

The objective is the task's own reward: cost = −(sum of the reward over the horizon), the quantity every
method here maximises. Rewards after a planning world is done (the episode's last step, or a simulation
blow-up, which the env resets inside the step) are not counted, and the planning envs never reset.
The model is exact: the planning worlds are clones of the evaluated ones, including the episode's drawn knob
friction and damping (``("sim", "params", ...)``), which the learnt policies never observe.

Compute per control step and evaluation world: K·H forward sim steps to sample, (refine_steps + 1)·H forward
and refine_steps·H backward steps to refine; ``metrics.json`` reports them (``sim_steps_per_control_step``,
``grad_steps_per_control_step``), their totals (``sim_steps``, ``grad_steps``) and, per evaluation episode, the
steps and the planning's CPU and wall seconds (``sim_steps_per_episode``, ``planning_cpu_s_per_episode``, ...).
"""

from __future__ import annotations

import logging
import sys
import time

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from ..progress import progress_bar
from ..envs import make_env
from ..envs.config import check_number
from ..envs.mirror import SignedPermutation, action_reflection, reflect_mirrored
from .budget import NO_TRAINING
from .evaluation import evaluate_policy
from .rundir import RunDirectory

__all__ = ["INTERPOLATIONS", "PLANNER_FIELDS", "PredictiveSampler", "STATE", "check_config", "spline_weights",
           "train"]

log = logging.getLogger(__name__)

INTERPOLATIONS = ("zero", "linear")
INITIAL_PLANS = ("hold", "zero")
OPTIMIZERS = ("adam", "sgd")
STATE = ("sim", "task", "info")  # what a step reads besides the action: a world's whole state


def check_config(a) -> None:
    """Raise one ``ValueError`` naming the first bad ``algo.*`` field of an MPC config ``a`` (a mapping).

    >>> check_config(dict(candidates=0, horizon=15, knots=4, noise=0.1, interpolation="linear", refine_steps=0,
    ...                   refine_lr=0.05, refine_optimizer="adam", initial_plan="hold"))
    Traceback (most recent call last):
    ValueError: algo.candidates must be an integer >= 1, got 0
    """
    def integer(name, low):
        value = a[name]
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"algo.{name} must be an integer >= {low}, got {value!r}")

    integer("candidates", 1)
    integer("horizon", 1)
    integer("knots", 1)
    integer("refine_steps", 0)
    for name, choices in (("interpolation", INTERPOLATIONS), ("initial_plan", INITIAL_PLANS),
                          ("refine_optimizer", OPTIMIZERS)):
        if a[name] not in choices:
            raise ValueError(f"algo.{name} must be one of {', '.join(choices)}, got {a[name]!r}")
    if a["knots"] > a["horizon"]:
        raise ValueError(f"algo.knots must be <= algo.horizon ({a['horizon']}), got {a['knots']}")
    check_number("algo.noise", a["noise"], strict=False)
    check_number("algo.refine_lr", a["refine_lr"])


def spline_weights(times: torch.Tensor, horizon: int, knots: int, interpolation: str) -> torch.Tensor:
    """``[len(times), knots]`` weights that evaluate a plan's knots at env-step ``times`` (0 = now).

    ``"zero"``: knot j holds over steps [j·H/M, (j+1)·H/M); ``"linear"``: knot j sits at step j·(H−1)/(M−1)
    and the action is interpolated between neighbours. Past the last knot the plan holds its last value, so
    a shifted plan repeats its final action.

    >>> spline_weights(torch.arange(4.0), horizon=4, knots=2, interpolation="zero")
    tensor([[1., 0.],
            [1., 0.],
            [0., 1.],
            [0., 1.]])
    >>> spline_weights(torch.tensor([0.0, 1.5, 3.0, 9.0]), horizon=4, knots=2, interpolation="linear")
    tensor([[1.0000, 0.0000],
            [0.5000, 0.5000],
            [0.0000, 1.0000],
            [0.0000, 1.0000]])
    """
    if interpolation == "zero" or knots == 1:
        index = (times * knots / horizon).floor().long().clamp(0, knots - 1)
        return torch.nn.functional.one_hot(index, knots).to(times.dtype)
    position = (times * (knots - 1) / max(horizon - 1, 1)).clamp(0, knots - 1)
    left = position.floor().long().clamp(max=knots - 2)
    frac = (position - left).unsqueeze(-1)
    one_hot = torch.nn.functional.one_hot
    return (1 - frac) * one_hot(left, knots).to(times.dtype) + frac * one_hot(left + 1, knots).to(times.dtype)


class PredictiveSampler(TensorDictModuleBase):
    """The planner as a torchrl policy for ``num_worlds`` worlds: reads each world's state, writes ``"action"``.

    ``sample_env``: ``num_worlds × candidates`` worlds of the evaluated task (gradients off);
    ``refine_env``: ``num_worlds`` worlds of it with gradients (needed when ``refine_steps`` > 0). Both must be
    functional (a step is a function of the TensorDict) and are never reset: :meth:`for_task` builds them
    for a registered task. ``state_keys``: the entries that hold a world's whole state; ``step_key``: its
    episode step counter (0 restarts the warm start). The planner keeps its plans between calls, so one
    instance follows one batch of episodes: ``env.rollout(steps, planner, auto_reset=False)``.
    ``progress``: a tqdm bar advanced once per control step (or None). ``mirror``: the action reflection of a
    mirrored task env (``task.mirror``) the planner acts in: its plans are the real scene's actions, so the
    worlds that env shows in the mirror get theirs reflected, and the env reflects them back. See the module
    docstring for a step.
    """

    def __init__(self, sample_env, refine_env=None, *, num_worlds: int, candidates: int = 32, horizon: int = 30,
                 knots: int = 4, noise: float = 0.5, interpolation: str = "linear", refine_steps: int = 2,
                 refine_lr: float = 0.05, refine_optimizer: str = "adam", initial_plan: str = "hold",
                 state_keys=STATE, step_key=("task", "step"), seed: int = 0, progress=None,
                 mirror: SignedPermutation | None = None):
        super().__init__()
        check_config(dict(candidates=candidates, horizon=horizon, knots=knots, noise=noise,
                          interpolation=interpolation, refine_steps=refine_steps, refine_lr=refine_lr,
                          refine_optimizer=refine_optimizer, initial_plan=initial_plan))
        if tuple(sample_env.batch_size) != (num_worlds * candidates,):
            raise ValueError(f"sample_env must have num_worlds x candidates = {num_worlds * candidates} worlds, "
                             f"got batch size {tuple(sample_env.batch_size)}")
        if refine_steps and (refine_env is None or tuple(refine_env.batch_size) != (num_worlds,)):
            raise ValueError(f"refine_steps = {refine_steps} needs a refine_env of {num_worlds} worlds with gradients")
        self.sample_env, self.refine_env = sample_env, refine_env
        self.in_keys, self.out_keys = list(state_keys), ["action"]
        self.state_keys, self.step_key = list(state_keys), step_key
        self.num_worlds, self.candidates, self.horizon, self.knots = num_worlds, candidates, horizon, knots
        self.noise, self.refine_steps, self.refine_lr = noise, refine_steps, refine_lr
        self.refine_optimizer, self.initial_plan, self.progress = refine_optimizer, initial_plan, progress
        self.mirror = mirror
        space = sample_env.action_spec_unbatched.space
        self.low, self.high = space.low, space.high
        dtype, device = self.low.dtype, self.low.device
        self.act_weights = spline_weights(torch.arange(horizon, dtype=dtype, device=device), horizon, knots,
                                          interpolation)  # [H, M]: knots -> the horizon's actions
        spacing = horizon / knots if interpolation == "zero" or knots == 1 else (horizon - 1) / (knots - 1)
        knot_times = torch.arange(knots, dtype=dtype, device=device) * spacing
        # [M, M]: the knots of the same plan one env step later (the old plan read at each knot's time + 1)
        self.shift_weights = spline_weights(knot_times + 1, horizon, knots, interpolation)
        self.generator = torch.Generator(device=device).manual_seed(seed)
        self.plan = None  # [N, M, A]: the current plan of every world
        self.stats = {"control_steps": 0, "sim_steps": 0, "grad_steps": 0, "noisy_wins": 0, "refined_wins": 0,
                      "refine_gain": 0.0}

    @classmethod
    def for_task(cls, task_cfg, num_worlds: int, candidates: int = 32, refine_steps: int = 2, device="cpu",
                 seed: int = 0, **kwargs) -> "PredictiveSampler":
        """A planner for ``num_worlds`` worlds of a registered task (a name or config, as ``make_env`` takes);
        ``kwargs``: the other planner options."""
        # the planning worlds are never reset, so their seed matters only for a world that blows up
        sample_env = make_env(task_cfg, num_envs=num_worlds * candidates, differentiable=False, raw=True,
                              seed=seed, device=device)
        refine_env = (make_env(task_cfg, num_envs=num_worlds, differentiable=True, raw=True, seed=seed,
                               device=device) if refine_steps else None)
        return cls(sample_env, refine_env, num_worlds=num_worlds, candidates=candidates, refine_steps=refine_steps,
                   seed=seed, mirror=action_reflection(sample_env), **kwargs)

    # ------------------------------------------------------------------------------------------ plans
    def actions(self, knots: torch.Tensor) -> torch.Tensor:
        """``[B, H, A]`` actions of plans ``knots`` [B, M, A]."""
        return torch.einsum("hm,bma->bha", self.act_weights, knots)

    def initial(self, state: TensorDictBase) -> torch.Tensor:
        """``[N, M, A]`` first plans: ``"hold"`` targets the hand's current joint positions at mid stiffness on a
        DexEnv with position or "vi" actions; otherwise (``"zero"``, torque actions, other envs) the plan is
        the middle of the action box."""
        env = self.sample_env
        first = ((self.low + self.high) / 2).expand(state.batch_size[0], -1).clone()
        if self.initial_plan == "hold" and getattr(env, "action_type", None) in ("position", "vi"):
            nu = env.scene.num_hand_dofs
            hand_q = state.get(("sim", "joint_q"))[:, :nu]
            first[:, :nu] = env.actions.actions_for_targets(hand_q.to(first.dtype))
        return first.clamp(self.low, self.high).unsqueeze(1).expand(-1, self.knots, -1).clone()

    def warm_start(self, state: TensorDictBase) -> torch.Tensor:
        """``[N, M, A]``: the previous plans one step later; :meth:`initial` where an episode starts."""
        if self.plan is None:
            return self.initial(state)
        fresh = state.get(self.step_key).reshape(-1) == 0
        shifted = torch.einsum("km,nma->nka", self.shift_weights, self.plan)
        return torch.where(fresh[:, None, None], self.initial(state), shifted)

    # ---------------------------------------------------------------------------------------- rollouts
    def plan_return(self, env, state: TensorDictBase, knots: torch.Tensor) -> torch.Tensor:
        """``[B]``: the summed reward of plans ``knots`` [B, M, A] from ``state`` [B] in ``env`` (B worlds),
        up to and including each world's first done step; differentiable when ``env`` is and ``knots`` require
        grad. ``state`` is not modified."""
        actions = self.actions(knots)
        td = state.copy()  # shallow: env.step writes "action" and "next" into td, not into the caller's state
        total = torch.zeros(actions.shape[0], 1, dtype=actions.dtype, device=actions.device)
        alive = torch.ones_like(total, dtype=torch.bool)
        for t in range(self.horizon):
            td.set("action", actions[:, t])
            td = env.step(td).get("next")
            total = total + torch.where(alive, td.get("reward"), 0.0)
            alive = alive & ~td.get("done")
        return total.squeeze(-1)

    @torch.no_grad()
    def sample(self, state: TensorDictBase, nominal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The nominal plans and ``candidates − 1`` noisy copies of them, rolled out from ``state`` [N]:
        ``(candidates [N, K, M, A], returns [N, K])``, candidate 0 the nominal."""
        n, k = self.num_worlds, self.candidates
        scale = self.noise * (self.high - self.low) / 2
        noise = torch.randn(n, k - 1, *nominal.shape[1:], generator=self.generator, dtype=nominal.dtype,
                            device=nominal.device) * scale
        candidates = torch.cat([nominal.unsqueeze(1), (nominal.unsqueeze(1) + noise).clamp(self.low, self.high)], 1)
        returns = self.plan_return(self.sample_env, state.repeat_interleave(k, dim=0),
                                   candidates.flatten(0, 1)).view(n, k)
        self.stats["sim_steps"] += n * k * self.horizon
        return candidates, returns

    def refine(self, state: TensorDictBase, knots: torch.Tensor, best_return: torch.Tensor):
        """``refine_steps`` gradient-ascent steps on the returns of plans ``knots`` [N, M, A] (whose returns are
        ``best_return`` [N]); per world, the best plan seen: the given one unless a refined one re-evaluates at
        least as high. Returns ``(knots, return)``."""
        best, sampled_return = knots, best_return
        knots = knots.clone().requires_grad_(True)
        if self.refine_optimizer == "adam":  # elementwise: each world's knots take their own step sizes
            optimizer = torch.optim.Adam([knots], lr=self.refine_lr, maximize=True)
        else:
            optimizer = torch.optim.SGD([knots], lr=self.refine_lr, maximize=True)
        n = self.num_worlds
        for i in range(self.refine_steps + 1):
            last = i == self.refine_steps
            with torch.set_grad_enabled(not last):  # the last pass only re-evaluates the last step's plan
                ret = self.plan_return(self.refine_env, state, knots)
                objective = ret.sum()  # the worlds are independent: the sum's gradient is each world's own
            self.stats["sim_steps"] += n * self.horizon
            if i > 0:  # pass 0 is the given plan itself: only its gradient is new
                better = ret.detach() >= best_return
                best = torch.where(better[:, None, None], knots.detach(), best)
                best_return = torch.where(better, ret.detach(), best_return)
            if last:
                break
            optimizer.zero_grad()
            objective.backward()
            self.stats["grad_steps"] += n * self.horizon
            with torch.no_grad():
                # stiff contact can overflow one world's float32 adjoint; that world skips the step, the others
                # are unaffected (their gradients do not depend on it)
                knots.grad[~torch.isfinite(knots.grad).flatten(1).all(1)] = 0.0
            optimizer.step()
            with torch.no_grad():
                knots.clamp_(self.low, self.high)
        self.stats["refined_wins"] += int((best_return > sampled_return).sum())
        self.stats["refine_gain"] += float((best_return - sampled_return).sum())
        return best, best_return

    # ------------------------------------------------------------------------------------------ policy
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if tuple(tensordict.batch_size) != (self.num_worlds,):
            raise ValueError(f"the planner was built for {self.num_worlds} worlds, got a TensorDict of batch size "
                             f"{tuple(tensordict.batch_size)}")
        state = tensordict.select(*self.state_keys).detach()
        candidates, returns = self.sample(state, self.warm_start(state))
        best = returns.argmax(1)  # a tie goes to the lowest index: the nominal keeps its place
        rows = torch.arange(self.num_worlds, device=best.device)
        plan, ret = candidates[rows, best], returns[rows, best]
        self.stats["noisy_wins"] += int((best > 0).sum())
        if self.refine_steps:
            plan, ret = self.refine(state, plan, ret)
        self.plan = plan
        self.stats["control_steps"] += 1
        if self.progress is not None:
            self.progress.update(1)
            self.progress.set_postfix(plan_return=f"{float(ret.mean()):.2f}")
        action = self.actions(plan)[:, 0]
        return tensordict.set("action", action if self.mirror is None else reflect_mirrored(state, action, self.mirror))

    def budget(self) -> dict:
        """The stated compute per control step and evaluation world, and what the planner has spent so far."""
        s, n = self.stats, max(self.stats["control_steps"] * self.num_worlds, 1)
        refine_passes = self.refine_steps + 1 if self.refine_steps else 0
        return {
            "sim_steps_per_control_step": (self.candidates + refine_passes) * self.horizon,
            "grad_steps_per_control_step": self.refine_steps * self.horizon,
            "sim_steps": s["sim_steps"], "grad_steps": s["grad_steps"],
            "noisy_candidate_win_rate": s["noisy_wins"] / n,  # a noisy plan beat the shifted nominal
            "refinement_win_rate": s["refined_wins"] / n,  # refinement raised the plan's return
            "mean_refinement_gain": s["refine_gain"] / n,  # the return it added, per world and control step
        }


PLANNER_FIELDS = ("candidates", "horizon", "knots", "noise", "interpolation", "refine_steps", "refine_lr",
                  "refine_optimizer", "initial_plan")


def train(cfg, overrides: list[str] | None = None) -> dict:
    """Evaluate the planner on ``cfg.eval.episodes`` episodes (no learning); returns the metrics dict, also
    written to ``metrics.json`` (and as the one row of ``metrics.jsonl``). Nothing to resume: ``resume=``
    is refused (``overrides`` are not used)."""
    check_config(cfg.algo)
    if cfg.eval.episodes < 1:
        raise ValueError(f"eval.episodes must be >= 1, got {cfg.eval.episodes}")
    with RunDirectory(cfg, overrides, resumes=False) as run:
        return _plan(run)


def _plan(run: RunDirectory) -> dict:
    cfg, a = run.cfg, run.cfg.algo
    torch.manual_seed(cfg.seed)
    episodes = cfg.eval.episodes
    planner = PredictiveSampler.for_task(cfg.task, episodes, **{name: a[name] for name in PLANNER_FIELDS},
                                         device=cfg.device, seed=cfg.seed)
    steps = planner.sample_env.max_episode_steps
    budget = planner.budget()
    log.info("mpc %s: %d episodes, %d candidates x %d steps (+%d refinement steps): %d sim steps (+%d backward) "
             "per control step and world", cfg.task.name, episodes, a.candidates, a.horizon, a.refine_steps,
             budget["sim_steps_per_control_step"], budget["grad_steps_per_control_step"])
    planner.progress = progress_bar(total=steps, desc=f"mpc {cfg.task.name}", disable=not cfg.progress, file=sys.stderr)
    start, start_cpu = time.perf_counter(), time.process_time()
    ev = evaluate_policy(planner, cfg.task, episodes, cfg.eval.seed, cfg.device, **run.record_options(live=False))
    wall, cpu = time.perf_counter() - start, time.process_time() - start_cpu
    planner.progress.close()
    counters = {"iteration": 0, "env_steps": episodes * steps, "wall_clock_s": 0.0}  # no training: 0 s of it
    # the planning is MPC's cost: the evaluation's, per episode (the episodes run side by side as worlds)
    cost = {**planner.budget(), "wall_clock_s": round(wall, 2), "planning_cpu_s": round(cpu, 2),
            "planning_wall_s_per_episode": round(wall / episodes, 4),
            "planning_cpu_s_per_episode": round(cpu / episodes, 4),
            "sim_steps_per_episode": planner.stats["sim_steps"] // episodes,
            "grad_steps_per_episode": planner.stats["grad_steps"] // episodes}
    row = {**ev, **cost, "iteration": 0, "env_steps": episodes * steps}
    run.log({k: v for k, v in row.items() if not isinstance(v, list)})
    # a training budget does not apply: nothing trains (dexmots-table reports "no training", not "0 s to 90 %")
    no_training = {"wall_clock_s": None, "env_steps": None, "cpu_s": None, "stopped_by": NO_TRAINING}
    return run.write_result(ev, counters, budget=no_training, **cost)
