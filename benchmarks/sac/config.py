"""The options of ``benchmarks/control_sac.py`` as one dataclass (:class:`SacConfig`, built by
:func:`benchmarks.sac.cli.parse_args`), and what follows from them: the start regimes, the reward, the SAC
hyperparameters, the result row's name, the learning curve's file stem and the command that reproduces a row.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, cast

from phast_gym.control import START_REGIMES, ControlProtocol
from phast_gym.systems.base import wrap
from phast_model.rl.loop import ZOO_PENDULUM_SAC
from phast_model.rl.observation import OBS_MODES

from .envs import check_regimes
from .rewards import PRECISE_WELLS, QUIET_WEIGHT, REWARDS, Reward, Well, format_wells, parse_wells, upright_quiet_weight

#: the agents: SAC on the plant, inside a PHAST world model (``phast_run``), on a Gymnasium env (alone)
AGENTS = ("sac-real", "sac-world", "sac-gym")


@dataclass(frozen=True)
class SacConfig:
    """The benchmark's options (``benchmarks/control_sac.py --help`` says what each does), in the order of its
    command line: :func:`command_line` writes them back in that order.  Comma lists (``agents``, ``net``,
    ``regimes``, ``wells``) are kept as given, for the rows' commands; the parsed values are :attr:`agent_names`,
    :func:`sac_hyperparameters`, :func:`regimes_of` and :func:`wells_of`.  ``__post_init__`` checks how the options
    combine (ValueError naming the bad one)."""

    out: str
    agents: str = "sac-real,sac-world"
    gym_env: str = "Pendulum-v1"
    gym_eval_episodes: int = 20
    curve: bool = False
    obs: str = "frames"
    quiet_weight: float | None = None
    wells: str | None = None
    mirror: bool = False
    net: str | None = None
    lr_final: float | None = None
    steps: int = 20000
    until_flat: bool = False
    max_steps: int = 150000
    eval_every: int = 2500
    eval_episodes: int = 10
    flat_window: int = 4
    flat_rel_tol: float = 0.05
    flat_abs_tol: float = 0.05
    reward: str = "zoo"
    env: str = ControlProtocol.env_id
    regimes: str | None = None
    sigma: float = 0.01
    trials_per_regime: int = 2
    repeat: int = 5
    episode_decisions: int = 200
    frames: int = 3
    burn_in: int = 10
    max_action: float = 10.0
    phast_run: str | None = None
    ec_estimators: str = "oracle,map,ukf"
    q_star: float = 0.0
    seed: int = 0
    progress: bool = True

    def __post_init__(self) -> None:
        if self.obs not in OBS_MODES:
            raise ValueError(f"obs must be one of {OBS_MODES}, got {self.obs!r}")
        if self.reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {self.reward!r}")
        agents = self.agent_names
        for a in agents:
            if a not in AGENTS:
                raise ValueError(f"unknown agent {a!r}")
            if a == "sac-world" and not self.phast_run:
                raise ValueError("sac-world needs --phast-run")
            if a == "sac-world" and self.obs != "frames":
                raise ValueError("sac-world observes frames only (the world model has no true state)")
        regimes_of(self)
        if self.mirror and abs(math.sin(self.q_star)) > 1e-9:
            raise ValueError("--mirror needs a target the reflection q -> -q keeps: q_star 0 or pi")
        if self.net is not None and not all(h.strip().isdigit() and int(h) > 0 for h in self.net.split(",")):
            raise ValueError(f"--net must be positive layer sizes like 64,64, got {self.net!r}")
        if self.lr_final is not None and not (self.lr_final > 0 and math.isfinite(self.lr_final)):
            raise ValueError(f"--lr-final must be a positive learning rate, got {self.lr_final!r}")
        if self.wells is not None:
            if self.reward != "precise":
                raise ValueError("--wells shapes the precise reward only (add --reward precise)")
            parse_wells(self.wells)
        if self.mirror and "sac-gym" in agents:
            raise ValueError("--mirror knows the plant agents' observations only (sac-real, sac-world)")
        if "sac-gym" in agents and len(agents) > 1:
            raise ValueError("sac-gym runs alone")

    @property
    def agent_names(self) -> list[str]:
        """The agents to train (``none``: the Energy-Casimir rows only)."""
        return [a for a in self.agents.split(",") if a and a != "none"]


def sac_hyperparameters(cfg: SacConfig) -> dict[str, Any]:
    """:data:`ZOO_PENDULUM_SAC` with ``net`` (hidden layer sizes) in place of its ``net_arch``."""
    hp = dict(ZOO_PENDULUM_SAC)
    if cfg.net:
        hp["policy_kwargs"] = {**hp["policy_kwargs"], "net_arch": [int(h) for h in cfg.net.split(",")]}
    return hp


def quiet_weight_of(cfg: SacConfig) -> float:
    """``quiet_weight``, or its default: :data:`QUIET_WEIGHT` at the hanging target ``q_star = 0`` (no holding torque
    needed), :func:`upright_quiet_weight` of the plant's ``m g l`` at any other target (see ``max_quiet_weight``)."""
    if cfg.quiet_weight is not None:
        return float(cfg.quiet_weight)
    if abs(float(wrap(float(cfg.q_star)))) < 1e-9:
        return QUIET_WEIGHT
    from phast_gym.control.evaluation import control_system

    return upright_quiet_weight(float(cast(Any, control_system(ControlProtocol(cfg.env))).mgl))


def regimes_of(cfg: SacConfig) -> tuple[str, ...]:
    """``regimes`` (start regimes of training, burn-ins and evaluation), or all of :data:`START_REGIMES`."""
    return tuple(START_REGIMES) if cfg.regimes is None else check_regimes(cfg.regimes.split(","))


def wells_of(cfg: SacConfig) -> tuple[Well, ...]:
    """``wells`` (the ``precise`` reward's angle wells), or :data:`PRECISE_WELLS`."""
    return PRECISE_WELLS if cfg.wells is None else parse_wells(cfg.wells)


def reward_of(cfg: SacConfig) -> Reward:
    """``reward`` with its quiet weight and wells."""
    return Reward(cfg.reward, quiet_weight_of(cfg), wells_of(cfg))


def method_tag(name: str, cfg: SacConfig) -> str:
    """Row name: ``agent/reward``, plus the non-default observation and quiet weight; ``sac-gym/<env id>``."""
    if name == "sac-gym":
        return f"sac-gym/{cfg.gym_env}"
    tag = f"{name}/{cfg.reward}"
    if cfg.reward != "zoo" and quiet_weight_of(cfg) != QUIET_WEIGHT:
        tag += f"/w{quiet_weight_of(cfg):g}"
    if cfg.reward == "precise" and wells_of(cfg) != PRECISE_WELLS:
        tag += f"/wells={format_wells(wells_of(cfg))}"
    if cfg.obs != "frames":
        tag += f"/obs={cfg.obs}"
    if cfg.net:
        tag += "/net" + "x".join(h.strip() for h in cfg.net.split(","))
    if cfg.lr_final is not None:
        tag += f"/lrf{cfg.lr_final:g}"
    if cfg.mirror:
        tag += "/mirror"
    return tag


def curve_stem(name: str, cfg: SacConfig) -> str:
    """File stem of an agent's learning curve (``curve_<agent>_<reward>`` as before for the default options)."""
    if name == "sac-gym":
        return f"curve_sac-gym_{cfg.gym_env}_s{cfg.seed}"
    tag = method_tag(name, cfg).replace("/", "_").replace("=", "-")
    return "curve_" + re.sub(r"[^A-Za-z0-9._+-]", "-", tag.replace(",", "+"))  # portable file names


def make_protocol(q_star: float, env_id: str = ControlProtocol.env_id) -> ControlProtocol:
    """The evaluation protocol of plant ``env_id``; upright (q_star = pi) uses the upright Energy-Casimir gains
    k_c = 20, d_inj = 3."""
    upright = abs(math.cos(q_star) + 1) < 1e-9
    return ControlProtocol(env_id, q_star=q_star, k_c=20.0 if upright else ControlProtocol.k_c,
                           d_inj=3.0 if upright else ControlProtocol.d_inj)


#: options that only the plant agents (sac-real / sac-world) and the Energy-Casimir rows read
SAC_PLANT_ONLY = ("env", "regimes", "wells", "obs", "reward", "quiet_weight", "sigma", "trials_per_regime", "repeat",
                  "episode_decisions", "frames", "burn_in",
                  "max_action", "phast_run", "ec_estimators", "q_star")
#: options of how a run is watched, not what it computes: left out of the commands
RUN_ONLY = ("progress",)


def command_line(cfg: SacConfig, agents: Sequence[str]) -> str:
    """The command that reproduces ``cfg`` with ``agents`` in place of ``--agents`` (the options the command's agents
    do not read left out)."""
    parts = ["python benchmarks/control_sac.py"]
    gym_only = list(agents) == ["sac-gym"]
    for f in fields(cfg):
        k, v = f.name, getattr(cfg, f.name)
        if k == "agents":
            v = ",".join(agents) or "none"
        if v is None or v is False or k in RUN_ONLY:
            continue
        if (k in ("gym_env", "gym_eval_episodes") and not gym_only) or (k in SAC_PLANT_ONLY and gym_only):
            continue  # options the command's agents do not read
        parts.append(f"--{k.replace('_', '-')}" + ("" if v is True else f" {v}"))
    return " ".join(parts)
