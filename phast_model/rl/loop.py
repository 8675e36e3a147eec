"""Policies from seconds on the machine: the model-based RL loop (docs/control.md, "Policies from seconds on
the machine").

    collect excitation -> fit PHAST (the rig path) -> train an SB3 agent in the world model -> run it on the plant
    -> add its episodes -> refit (warm-started, on all recordings) -> ...

until the task succeeds on the plant (every episode of an iteration passes the quiet criterion) or the plant-time
budget is spent.  Every plant sample used for learning is counted (:attr:`LoopResult.plant_seconds`): the excitation
recordings and the policy's own episodes.  The world-model episodes start from windows of those recordings
(:mod:`.world_env`), so they cost nothing more.  The final evaluation (``eval_trials`` episodes, not used for
learning) is reported apart.

* the fit is the rig path of ``phast-train --recordings`` (:func:`phast_model.train.rig_fit.load_rig_data`,
  ``rig_config``,
  ``build``, ``fit_recordings``): PARTIAL, the rig description's templates with every coefficient refitted and the
  joint friction learned; later iterations continue from the previous model (warm start, ``refit_epochs``);
* the agent is SB3's (SAC by default, reflection-equivariant for symmetric plants: :mod:`.mirror_policy`), trained
  with SB3's ``EvalCallback`` + ``StopTrainingOnNoModelImprovement`` on a world-model eval env and a
  linear learning-rate schedule (``LinearSchedule``); later iterations continue the same agent in the refitted model;
* the deployed controller is :class:`.hold.HybridPolicy`: the agent, and near the target a hold built from the
  learned model (the quiet criterion): Energy-Casimir when the input acts on every coordinate, else LQR of the
  learned linearisation (a cart-pole; see :mod:`.hold`).
* with ``agent_kind="mpc"`` (``phast-rl --agent mpc``) nothing is trained: the deployed controller plans in the model
  just fitted (:class:`.planner.PlannerPolicy`, MPPI through the learned core), with the same hold.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any, cast

import gymnasium as gym
import numpy as np

from phast_gym.systems.base import System

from ..control.mppi import MPPISpec
from ..world.model import PHAST
from .hold import HoldConfig, HoldGains, HybridPolicy, LQRGains, make_hold
from .planner import AGENTS, planner_policy
from .plant import (
    Episode,
    HeldTorques,
    PlantSpec,
    Task,
    excitation_inputs,
    make_plant,
    quiet_metrics,
    record_episode,
    to_recordings,
)
from .sources import Prior, join_recordings, load_prior
from .types import Agent, Plant, Policy
from .world_env import WorldTask, WorldTaskEnv, burn_in_pool

if TYPE_CHECKING:
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm


@dataclass(frozen=True)
class FitSpec:
    """The world model: the rig description ``sim`` (None: :func:`.descriptions.default_description` of the plant's env
    id) with ``sim_kwargs``, the regime,
    epochs of the first fit and of each warm-started refit, the multiple-shooting window, the joint friction's laws."""

    sim: str | None = None
    sim_kwargs: dict[str, Any] = field(default_factory=dict)
    regime: str = "partial"
    epochs: int = 60
    refit_epochs: int = 30
    window_s: float = 0.5
    # the joint friction's laws (None: the description's, else the rig path's)
    friction_laws: tuple[str, ...] | None = None


@dataclass(frozen=True)
class AgentSpec:
    """The SB3 agent: algorithm (``sac``, ``td3``), decisions of the first training and of each later one, the
    world-model evaluation (``eval_every`` decisions, ``eval_episodes``; training stops after ``patience``
    evaluations without improvement, at least ``min_evals``), episode length in decisions, observation frames,
    learning rate from ``lr`` to ``lr_final`` (SB3 ``LinearSchedule``), hidden layers, the mirror symmetry (SAC only),
    the reward's weights on |qdot|^2 and on the squared Euclidean errors, whether episodes start with the Euclidean
    coordinates moved to 0 (``recenter``; :class:`.world_env.WorldTaskEnv`).  ``final_steps`` is the training of the
    last iteration, the one without a plant episode (the budget spent; None: ``refit_steps``): it costs no plant time.
    ``keep_best``: after each training the agent takes the weights of its best world-model evaluation (SB3's
    ``EvalCallback`` ``best_model_save_path``), not those it stopped with.  ``hold_goal``: a world-model episode ends
    with the best reward once the state enters the hold's handoff region (:class:`.world_env.WorldTask` ``goal``)."""

    algo: str = "sac"
    steps: int = 8_000
    refit_steps: int = 4_000
    final_steps: int | None = None
    keep_best: bool = False
    hold_goal: bool = False
    eval_every: int = 2_000
    eval_episodes: int = 10
    patience: int = 3
    min_evals: int = 3
    episode_decisions: int = 60
    frames: int = 3
    lr: float = 1e-3
    lr_final: float = 3e-4
    net: tuple[int, ...] = (64, 64)
    mirror: bool = True
    velocity_weight: float = 0.1
    position_weight: float = 1.0
    recenter: bool = True

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ValueError(f"algo must be one of {ALGOS}, got {self.algo!r}")
        for k in ("steps", "refit_steps", "eval_every", "eval_episodes", "patience", "min_evals", "episode_decisions",
                  "frames"):
            v = getattr(self, k)
            if int(v) != v or v < 1:
                raise ValueError(f"{k} must be a positive integer, got {v!r}")
        if self.final_steps is not None and (int(self.final_steps) != self.final_steps or self.final_steps < 1):
            raise ValueError(f"final_steps must be a positive integer or None, got {self.final_steps!r}")
        for k in ("velocity_weight", "position_weight"):
            v = getattr(self, k)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"{k} must be a finite number >= 0, got {v!r}")


#: SB3 algorithms the loop builds (continuous actions)
ALGOS = ("sac", "td3")
#: the RL zoo's tuned SAC hyperparameters for Pendulum-v1 (rl-baselines3-zoo hyperparams/sac.yml: ``policy MlpPolicy,
#: learning_rate 1e-3, n_timesteps 20000``); the rest are SB3's SAC defaults, written out so the JSON records them.
#: The loop's SAC takes them but the learning rate and the network (:class:`AgentSpec`); the SAC benchmark
#: (``benchmarks/sac``) all of them.
ZOO_PENDULUM_SAC: dict[str, Any] = {
    "learning_rate": 1e-3, "buffer_size": 1_000_000, "learning_starts": 100, "batch_size": 256, "tau": 0.005,
    "gamma": 0.99, "train_freq": 1, "gradient_steps": 1, "ent_coef": "auto", "use_sde": False,
    "policy_kwargs": {"net_arch": [256, 256]},
}


@dataclass(frozen=True)
class LoopConfig:
    """The whole loop: plant, task, plant-time budget (s), seed, plant episodes (``episode_s`` each; excitation
    first, then ``policy_episodes`` per iteration), the excitation's random inputs (``torque_std`` held
    ``hold_decisions`` decisions), the final evaluation (``eval_trials`` x ``eval_s``, not counted).  ``recordings``
    made before the loop are learned from first and count against the budget; ``offline``: nothing but them (the
    plant spec then only describes the rig)."""

    plant: PlantSpec = field(default_factory=PlantSpec)
    task: Task = field(default_factory=Task)
    budget_s: float = 30.0
    seed: int = 0
    episode_s: float = 5.0
    excitation_episodes: int = 2
    policy_episodes: int = 1
    torque_std: float = 5.0
    hold_decisions: int = 4
    max_iterations: int = 20
    eval_trials: int = 10
    eval_s: float = 30.0
    fit: FitSpec = field(default_factory=FitSpec)
    agent: AgentSpec = field(default_factory=AgentSpec)
    hold: HoldConfig = field(default_factory=HoldConfig)
    recordings: str | None = None  # recordings from before the loop (:func:`.sources.load_prior`), learned from first
    offline: bool = False  # no plant at all: learn from ``recordings`` alone, no plant episode, no evaluation
    agent_kind: str = "sac"  # :data:`.planner.AGENTS`: ``sac`` (``agent``, trained in the model), ``mpc`` (``planner``)
    planner: MPPISpec = field(default_factory=MPPISpec)

    def __post_init__(self) -> None:
        if self.agent_kind not in AGENTS:
            raise ValueError(f"agent_kind must be one of {AGENTS}, got {self.agent_kind!r}")
        for k in ("budget_s", "episode_s", "eval_s", "torque_std"):
            v = getattr(self, k)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{k} must be a positive number, got {v!r}")
        for k in ("policy_episodes", "hold_decisions", "max_iterations", "eval_trials"):
            v = getattr(self, k)
            if int(v) != v or v < 1:
                raise ValueError(f"{k} must be a positive integer, got {v!r}")
        if int(self.excitation_episodes) != self.excitation_episodes or self.excitation_episodes < 0:
            raise ValueError(f"excitation_episodes must be an integer >= 0, got {self.excitation_episodes!r}")
        if self.recordings is None and (self.offline or self.excitation_episodes == 0):
            raise ValueError("without recordings the loop needs excitation episodes (--excitation-episodes >= 1); "
                             "--offline learns from --recordings alone")
        if self.excitation_episodes * self.episode_s > self.budget_s + 1e-9:
            raise ValueError(f"the excitation alone ({self.excitation_episodes} x {self.episode_s} s) exceeds the "
                             f"budget of {self.budget_s} s: lower --excitation-episodes or --episode-s, or raise "
                             "--budget-s")

    @property
    def episode_steps(self) -> int:
        """Plant steps per learning episode (a whole number of decisions)."""
        k = self.plant.decision_steps
        return max(2, int(round(self.episode_s / self.plant.decision_dt))) * k

    @property
    def sim(self) -> str:
        """The rig description: ``fit.sim``, else the plant's (:func:`.descriptions.default_description`)."""
        from .descriptions import default_description

        return self.fit.sim or default_description(self.plant.env_id)


@dataclass
class IterationResult:
    """One pass of the loop: the fit (validation RMSE, first-epoch train RMSE: low when warm-started, seconds), the
    agent's training (decisions, SB3 evaluations in the world model), the plant episodes it ran (quiet-criterion
    success and angle-only success per episode, RMS input) and the plant seconds used so far."""

    iteration: int
    warm_started: bool
    fit_val_rmse: float
    fit_first_train_rmse: float
    fit_seconds: float
    agent_decisions: int
    agent_seconds: float
    world_eval_timesteps: list[int]
    world_eval_returns: list[float]
    plant_success: list[bool]
    plant_success_angle_only: list[bool]
    plant_rms_input: list[float]
    plant_handoffs: list[int]
    plant_seconds: float
    hold_gains: dict[str, Any] | None

    @property
    def success(self) -> bool:
        """Every plant episode of this iteration passed the quiet criterion."""
        return bool(self.plant_success) and all(self.plant_success)


@dataclass
class Evaluation:
    """The final evaluation on the plant (``trials`` episodes from the task's starts; not used for learning)."""

    success: float
    success_angle_only: float
    rms_torque: float
    final_error: float
    trials: int
    seconds: float
    trial_success: list[bool]
    trial_rms: list[float]
    act_ms: dict[str, float] = field(default_factory=dict)  # the controller's time per plant step: mean, p99, max


@dataclass
class LoopResult:
    """What :func:`run_loop` returns: the iterations, the plant seconds used for learning, whether an iteration
    succeeded on the plant, the final evaluation, the trained agent and world model, the wall time and the recordings
    the model was last fitted to (the ``phast-train --recordings`` format)."""

    iterations: list[IterationResult]
    plant_seconds: float
    learning_succeeded: bool
    evaluation: Evaluation | None  # None: offline (no plant to evaluate on)
    agent: Agent | None  # None: the planner (``agent_kind="mpc"``), rebuilt from the model and the config
    model: PHAST
    wall_s: float
    budget_s: float
    recordings: dict[str, Any] = field(default_factory=dict)  # every plant episode used for learning (rig format)
    prior_seconds: float = 0.0  # of plant_seconds, those of the recordings from before the loop
    config: LoopConfig | None = None  # the configuration the loop ran with

    def summary(self) -> dict[str, Any]:
        """summary.json: ``plant_seconds``, ``success`` (quiet criterion), ``success_angle_only``, ``rms_torque`` (the
        final evaluation; None offline), ``iterations`` (per-iteration success and learning record)."""
        ev = self.evaluation
        final: dict[str, Any] = {"success": None, "success_angle_only": None, "rms_torque": None, "final_error": None,
                                 "eval_trials": 0, "eval_plant_seconds": 0.0, "trial_success": [],
                                 "trial_rms_torque": [],
                                 "controller_ms": {}}
        if ev is not None:
            final = {"success": ev.success, "success_angle_only": ev.success_angle_only, "rms_torque": ev.rms_torque,
                     "final_error": ev.final_error, "eval_trials": ev.trials, "eval_plant_seconds": ev.seconds,
                     "trial_success": ev.trial_success, "trial_rms_torque": ev.trial_rms, "controller_ms": ev.act_ms}
        return {"plant_seconds": round(self.plant_seconds, 6), "budget_s": self.budget_s, **final,
                "prior_seconds": round(self.prior_seconds, 6), "learning_succeeded": self.learning_succeeded,
                "iteration_success": [it.success for it in self.iterations],
                "iterations": [{**asdict(it), "success": it.success} for it in self.iterations],
                "wall_s": round(self.wall_s, 1)}


# --------------------------------------------------------------------------- stages
def collect_excitation(cfg: LoopConfig, plant: Plant, seed: int) -> list[Episode]:
    """The excitation episodes: random inputs held ``hold_decisions`` decisions from the task's starts (seeded)."""
    rng = np.random.default_rng(seed)
    x0 = cfg.task.start_states(plant.system, rng, cfg.excitation_episodes)
    hold_steps = cfg.hold_decisions * cfg.plant.decision_steps
    return [record_episode(plant,
                           HeldTorques(excitation_inputs(rng, cfg.episode_steps, plant.m, hold_steps, cfg.torque_std,
                                                         cfg.plant.max_action)),
                           x, cfg.episode_steps, int(rng.integers(2**31)), "excitation") for x in x0]


@dataclass
class FitOutcome:
    model: PHAST
    val_rmse: float
    first_train_rmse: float
    seconds: float
    lr_mult: float = 1.0  # the learning rates' factor the fit ran at (its refits keep it)


def fit_world_model(cfg: LoopConfig, recordings: dict[str, Any], model: PHAST | None,
                    lr_mult: float | None = None) -> FitOutcome:
    """Fit PHAST to all recordings so far by the rig path; continue from ``model`` when given (warm start: the
    rig-template initialisation is skipped and ``refit_epochs`` run at ``lr_mult``, the first fit's rate factor).

    The first fit's factor is the rig path's (:func:`phast_model.train.rig_fit.lr_mult`): 1, or 1% after UNKNOWN's start
    from the recorded motion, a fitted model that is refined, not relearned.  Refits keep it: at the base rates the
    first UNKNOWN refit of the pendulum undid the start (validation RMSE 0.008 -> 0.24 rad, the upright no longer a
    maximum of V_hat)."""
    from ..train.rig_fit import RigTrainConfig, build, fit_recordings, load_rig_data, rig_config
    from ..train.rig_fit import lr_mult as rig_lr_mult

    data = load_rig_data(recordings, cfg.sim, cfg.fit.sim_kwargs)
    if model is None:
        from .descriptions import friction_laws

        declared = cfg.fit.friction_laws if cfg.fit.friction_laws is not None else friction_laws(cfg.sim)
        laws: dict[str, Any] = {} if declared is None else {"friction_laws": list(declared)}
        mcfg = rig_config(cfg.sim, cfg.fit.sim_kwargs, cfg.fit.regime, data, seed=cfg.seed,
                          action_bound=[cfg.plant.max_action] * data.train.u.shape[-1] if data.train.u is not None
                          else None,
                          **laws)
        model, epochs = build(mcfg), cfg.fit.epochs
    else:
        model.config = replace(model.config, init_from="none")  # warm start: keep the fitted coefficients
        epochs = cfg.fit.refit_epochs
    tcfg = RigTrainConfig(epochs=epochs, window_s=cfg.fit.window_s, seed=cfg.seed, progress=False, lr_mult=lr_mult)
    factor = rig_lr_mult(model, tcfg)
    fit = fit_recordings(model, data, tcfg)
    first = float(fit.history[0]["train_rmse"]) if fit.history else float("nan")
    return FitOutcome(fit.model, float(fit.best_val), first, float(fit.wall_time_s), factor)


def algo_class(name: str) -> type[OffPolicyAlgorithm]:
    """The SB3 algorithm ``name`` of :data:`ALGOS`."""
    import stable_baselines3 as sb3

    algos: dict[str, type[OffPolicyAlgorithm]] = {"sac": sb3.SAC, "td3": sb3.TD3}
    return algos[name]


def make_agent(cfg: LoopConfig, env: gym.Env) -> Agent:
    """The SB3 agent on ``env``: the RL zoo's Pendulum SAC hyperparameters, a linear learning-rate schedule (SB3
    ``LinearSchedule``, formerly ``get_linear_fn``), the mirror-equivariant policy for SAC when ``agent.mirror``
    (reflection q -> -q, u -> -u)."""
    from stable_baselines3.common.utils import LinearSchedule

    from .mirror_policy import MirrorSACPolicy, mirror_signs

    spec = cfg.agent
    lr = LinearSchedule(spec.lr, spec.lr_final, 1.0)
    kwargs: dict[str, Any] = {"policy_kwargs": {"net_arch": list(spec.net)}}
    if spec.algo == "sac":
        hp = {k: v for k, v in ZOO_PENDULUM_SAC.items() if k not in ("learning_rate", "policy_kwargs")}
        kwargs.update(hp)
    policy: str | type[MirrorSACPolicy] = "MlpPolicy"
    if spec.algo == "sac" and spec.mirror:
        policy = MirrorSACPolicy
        kwargs["policy_kwargs"]["mirror"] = mirror_signs(int(cast(gym.spaces.Box, env.observation_space).shape[0]) // 2)
    return algo_class(spec.algo)(policy, env, learning_rate=lr, seed=cfg.seed, verbose=0, **kwargs)


@dataclass
class AgentOutcome:
    agent: Agent | None
    decisions: int
    seconds: float
    eval_timesteps: list[int]
    eval_returns: list[float]


def training_steps(spec: AgentSpec, first: bool, last: bool) -> int:
    """Decisions of this training: the first, a later one, or the last (no plant episode follows it)."""
    if first:
        return spec.steps
    return spec.final_steps if last and spec.final_steps is not None else spec.refit_steps


def train_agent(cfg: LoopConfig, model: PHAST, pool: np.ndarray, q_star: np.ndarray, agent: Agent | None,
                iteration: int, actuated: list[int] | None = None, last: bool = False) -> AgentOutcome:
    """Train (or continue) the agent in the world model with SB3's ``EvalCallback`` and
    ``StopTrainingOnNoModelImprovement`` on a second world-model env (its own burn-in draws); ``last``: no plant
    episode follows (``AgentSpec.final_steps``)."""
    import os
    import tempfile

    from stable_baselines3.common.callbacks import EvalCallback, StopTrainingOnNoModelImprovement
    from stable_baselines3.common.monitor import Monitor

    spec, t0 = cfg.agent, time.perf_counter()

    def env(seed: int) -> Monitor:
        goal = cfg.hold if spec.hold_goal and cfg.hold.enabled else None
        task = WorldTask(q_star, cfg.plant.max_action, cfg.plant.sigma, spec.episode_decisions, spec.frames,
                         spec.velocity_weight, spec.position_weight, spec.recenter, goal)
        return Monitor(WorldTaskEnv(model, pool, task, seed=seed, actuated=actuated))

    train_env = env(cfg.seed * 1000 + iteration)
    first = agent is None
    if agent is None:
        agent = make_agent(cfg, train_env)
    else:
        agent.set_env(train_env)
    stop = StopTrainingOnNoModelImprovement(max_no_improvement_evals=spec.patience, min_evals=spec.min_evals)
    start = agent.num_timesteps
    with tempfile.TemporaryDirectory() as log:  # EvalCallback keeps its evaluations only when it has a log_path
        ev = EvalCallback(env(cfg.seed * 1000 + 500 + iteration), n_eval_episodes=spec.eval_episodes,
                          eval_freq=spec.eval_every, log_path=log, callback_after_eval=stop, deterministic=True,
                          verbose=0,
                          best_model_save_path=log if spec.keep_best else None)
        agent.learn(total_timesteps=training_steps(spec, first, last), callback=ev, reset_num_timesteps=first,
                    progress_bar=False)
        returns = [float(np.mean(r)) for r in ev.evaluations_results]
        best = os.path.join(log, "best_model.zip")
        if spec.keep_best and returns and returns[-1] < max(returns) and os.path.exists(best):
            agent.set_parameters(best)  # the policy and critics of the best evaluation; the replay buffer stays
    return AgentOutcome(agent, int(agent.num_timesteps - start), time.perf_counter() - t0,
                        [int(t) for t in ev.evaluations_timesteps], returns)


def deployed_policy(cfg: LoopConfig, agent: Policy | None, model: PHAST, system: System, actuated: list[int],
                    q_star: np.ndarray) -> tuple[HybridPolicy, HoldGains | LQRGains | None]:
    """The controller run on the plant (``system`` its description, ``actuated`` its driven coordinates): the agent,
    with the hold of the learned model when enabled (Energy-Casimir when the plant is fully actuated, else LQR:
    :func:`.hold.make_hold`); with ``cfg.agent_kind == "mpc"`` the planner in ``model`` (:mod:`.planner`; ``agent``
    unused)."""
    if cfg.agent_kind == "mpc":
        return planner_policy(model, cfg.planner, q_star, cfg.plant, cfg.hold, actuated, cfg.seed)
    if agent is None:
        raise ValueError("an SB3 agent's controller needs the trained agent")
    hold, gains = None, None
    if cfg.hold.enabled:
        hold, gains = make_hold(model, q_star, cfg.plant.dt, cfg.plant.sigma, cfg.plant.max_action, cfg.hold, actuated)
    return HybridPolicy(agent, cfg.agent.frames, cfg.plant.decision_steps, cfg.plant.max_action, q_star, hold, cfg.hold,
                        system.angle_dims), gains


def run_policy(cfg: LoopConfig, plant: Plant, policy: HybridPolicy, n: int, steps: int, seed: int,
               kind: str) -> list[Episode]:
    """``n`` plant episodes of ``steps`` steps of the deployed policy from the task's starts (seeded)."""
    rng = np.random.default_rng(seed)
    x0 = cfg.task.start_states(plant.system, rng, n)
    out = []
    for x in x0:
        ep = record_episode(plant, policy, x, steps, int(rng.integers(2**31)), kind)
        ep.handoffs = policy.handoffs
        out.append(ep)
    return out


def evaluate(cfg: LoopConfig, plant: Plant, policy: HybridPolicy, q_star: np.ndarray) -> Evaluation:
    """The final evaluation: ``eval_trials`` episodes of ``eval_s`` seconds, quiet criterion on each."""
    steps = int(round(cfg.eval_s / cfg.plant.dt))
    eps = run_policy(cfg, plant, policy, cfg.eval_trials, steps, cfg.seed * 7919 + 104_729, "evaluation")
    ms = [quiet_metrics(e, q_star, plant.system.angle_dims, cfg.task) for e in eps]
    return Evaluation(float(np.mean([m.success for m in ms])), float(np.mean([m.settled for m in ms])),
                      float(np.mean([m.rms_input for m in ms])), float(np.mean([m.final_error for m in ms])), len(ms),
                      float(sum(e.seconds for e in eps)), [m.success for m in ms], [round(m.rms_input, 5) for m in ms],
                      act_ms(eps))


def act_ms(episodes: list[Episode]) -> dict[str, float]:
    """The controller's compute time per plant step over ``episodes`` in ms (mean, 99th percentile, max): on a real
    machine it must fit in the step ``dt``, beside the driver's own I/O."""
    t = np.concatenate([e.act_s for e in episodes if e.act_s is not None] or [np.zeros(1)]) * 1e3
    return {"mean": round(float(t.mean()), 3), "p99": round(float(np.percentile(t, 99)), 3),
            "max": round(float(t.max()), 3)}


# --------------------------------------------------------------------------- the loop
@dataclass
class _Data:
    """What the world model is fitted to: the recordings from before the loop and the plant episodes so far."""

    prior: Prior | None
    episodes: list[Episode]

    @property
    def seconds(self) -> float:
        return (0.0 if self.prior is None else self.prior.seconds) + sum(e.seconds for e in self.episodes)

    def recordings(self, cfg: LoopConfig, plant: Plant) -> dict[str, Any]:
        """All of it in the rig format (with the actuated coordinates of an underactuated plant)."""
        dofs = list(plant.actuated_dofs) if plant.m < plant.n else None
        recs = (to_recordings(self.episodes, cfg.plant.decision_steps, plant.system.angle_dims, dofs)
                if self.episodes else None)
        return join_recordings(None if self.prior is None else self.prior.recordings, recs)


def first_data(cfg: LoopConfig, plant: Plant) -> _Data:
    """The recordings from before the loop (when given) and the excitation episodes on the plant (none offline)."""
    prior = None
    if cfg.recordings is not None:
        prior = load_prior(cfg.recordings, plant.system, list(plant.actuated_dofs), cfg.plant.decision_dt,
                           cfg.episode_steps // cfg.plant.decision_steps)
        if not cfg.offline and prior.seconds + cfg.excitation_episodes * cfg.episode_s > cfg.budget_s + 1e-9:
            raise ValueError(f"the recordings ({prior.seconds:g} s) and the excitation ({cfg.excitation_episodes} x "
                             f"{cfg.episode_s:g} s) exceed the budget of {cfg.budget_s:g} s")
    episodes = [] if cfg.offline or not cfg.excitation_episodes else collect_excitation(cfg, plant, cfg.seed)
    return _Data(prior, episodes)


#: progress callback: (stage text, plant seconds used so far)
Progress = Callable[[str, float], None]


def _no_progress(stage: str, seconds: float) -> None:
    return None


class LoopInterrupted(RuntimeError):
    """The loop stopped before its end (an error on the plant, a fit or a training; Ctrl-C): ``recordings`` holds
    every plant episode recorded so far (the rig format; ``--recordings`` continues from them), ``seconds`` their
    plant time, ``cause`` what stopped it."""

    def __init__(self, cause: BaseException, recordings: dict[str, Any], seconds: float) -> None:
        super().__init__(f"{type(cause).__name__}: {cause}" if str(cause) else type(cause).__name__)
        self.cause, self.recordings, self.seconds = cause, recordings, float(seconds)


@dataclass
class _Learner:
    """The loop's learned parts: the world model and the agent (None before the first fit and training)."""

    model: PHAST | None = None
    agent: Agent | None = None
    lr_mult: float | None = None  # the first fit's learning-rate factor, kept by the refits

    def trained(self) -> tuple[Agent | None, PHAST]:
        """The agent (None for the planner) and the world model once an iteration has made them."""
        if self.model is None:
            raise RuntimeError("no iteration of the loop has run")
        return self.agent, self.model


def _iteration(cfg: LoopConfig, plant: Plant, data: _Data, learner: _Learner, it: int,
               progress: Progress) -> IterationResult:
    """Fit (warm-started after the first), train the agent, run it on the plant while the budget allows."""
    q_star = cfg.task.target(plant.system)
    recs = data.recordings(cfg, plant)
    warm = learner.model is not None
    fit = fit_world_model(cfg, recs, learner.model, learner.lr_mult)
    learner.model, learner.lr_mult = fit.model, fit.lr_mult
    progress(f"iteration {it}: fitted (val RMSE {fit.val_rmse:.4f})", data.seconds)
    pool = burn_in_pool(recs["q"], fit.model.observer.window)
    ep_s = cfg.episode_steps * cfg.plant.dt
    can_run = not cfg.offline and data.seconds + cfg.policy_episodes * ep_s <= cfg.budget_s + 1e-9
    trained = AgentOutcome(None, 0, 0.0, [], [])  # the planner: nothing to train
    if cfg.agent_kind != "mpc":
        trained = train_agent(cfg, fit.model, pool, q_star, learner.agent, it, list(plant.actuated_dofs),
                              last=not can_run)
        learner.agent = trained.agent
        progress(f"iteration {it}: agent trained ({trained.decisions} decisions)", data.seconds)
    new: list[Episode] = []
    policy, gains = deployed_policy(cfg, trained.agent, fit.model, plant.system, list(plant.actuated_dofs), q_star)
    if can_run:
        new = run_policy(cfg, plant, policy, cfg.policy_episodes, cfg.episode_steps, cfg.seed * 1000 + 77 + it,
                         "policy")
    data.episodes += new
    ms = [quiet_metrics(e, q_star, plant.system.angle_dims, cfg.task) for e in new]
    progress(f"iteration {it}: {sum(m.success for m in ms)}/{len(ms)} plant episodes quiet (angle only "
             f"{sum(m.settled for m in ms)}, final angle error {[round(m.final_error, 3) for m in ms]}, RMS input "
             f"{[round(m.rms_input, 3) for m in ms]}, handoffs {[e.handoffs for e in new]})", data.seconds)
    return IterationResult(it, warm, fit.val_rmse, fit.first_train_rmse, fit.seconds, trained.decisions,
                           trained.seconds, trained.eval_timesteps, trained.eval_returns,
                           [m.success for m in ms], [m.settled for m in ms], [m.rms_input for m in ms],
                           [e.handoffs for e in new], data.seconds, None if gains is None else asdict(gains))


def run_loop(cfg: LoopConfig, progress: Progress = _no_progress, plant: Plant | None = None) -> LoopResult:
    """Run the loop of the module docstring and the final evaluation (none offline) on ``plant`` (default: made
    from ``cfg.plant``; a machine's is closed at the end)."""
    import torch

    t0 = time.perf_counter()
    torch.manual_seed(cfg.seed)
    plant = make_plant(cfg.plant) if plant is None else plant
    data: _Data | None = None
    try:
        data = first_data(cfg, plant)
        progress("recordings and excitation" if data.prior is not None else "excitation", data.seconds)
        learner = _Learner()
        iterations: list[IterationResult] = []
        for it in range(cfg.max_iterations):
            iterations.append(_iteration(cfg, plant, data, learner, it, progress))
            ran = bool(iterations[-1].plant_success)
            if iterations[-1].success or not ran:
                break
        agent, model = learner.trained()
        ev = None
        if not cfg.offline:
            q_star = cfg.task.target(plant.system)
            policy, _ = deployed_policy(cfg, agent, model, plant.system, list(plant.actuated_dofs), q_star)
            ev = evaluate(cfg, plant, policy, q_star)
    except (Exception, KeyboardInterrupt) as exc:
        if data is None:
            raise
        raise LoopInterrupted(exc, data.recordings(cfg, plant), data.seconds) from exc
    finally:
        close = getattr(plant, "close", None)
        if callable(close):
            close()
    return LoopResult(iterations, data.seconds, any(i.success for i in iterations), ev, agent, model,
                      time.perf_counter() - t0, cfg.budget_s, data.recordings(cfg, plant),
                      0.0 if data.prior is None else data.prior.seconds, cfg)
