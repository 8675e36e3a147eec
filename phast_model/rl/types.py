"""The loop's parts as types (as SB3's ``common/type_aliases.py`` names its own): what the loop asks of the plant it
steps, of the controller it runs there and of the agent it trains and deploys.

* :class:`Plant`: a phast_gym env (:func:`.plant.make_plant`: ``PortHamiltonianEnv``) or a machine adapted to the
  same interface (:class:`.sources.MachinePlant`);
* :class:`Controller`: what runs on the plant every step (:class:`.hold.HybridPolicy`, the excitation's
  :class:`.plant.HeldTorques`);
* :class:`Policy`: what the deployed controller asks of the agent (SB3's ``PolicyPredictor`` and the action space);
  :class:`Agent`: what the loop trains (an SB3 off-policy algorithm, SAC or TD3, as far as the loop uses it).

The world model needs no protocol: the loop fits, warm-starts and saves the PHAST model itself
(:class:`phast_model.world.model.PHAST`, which the rig path's ``fit_recordings``, ``save_run`` and the hold take).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, SupportsFloat

import gymnasium as gym
import numpy as np

from phast_gym.systems.base import System

if TYPE_CHECKING:
    import torch
    from stable_baselines3.common.callbacks import BaseCallback


class Plant(Protocol):
    """The plant of the loop: ``reset`` to a true state (``options={"state": x0}``; a machine resets itself) and
    ``step`` with inputs ``u`` (m,), both returning the noisy measured q (n,) and ``info["state"]``, the true state
    (metrics only; a machine: the measured q and NaN momenta); ``system`` says what the coordinates are, ``dt`` the
    step (s), ``actuated_dofs`` the coordinates the m inputs drive, ``max_action`` their bound."""

    @property
    def system(self) -> System: ...

    @property
    def n(self) -> int: ...

    @property
    def m(self) -> int: ...

    @property
    def dt(self) -> float: ...

    @property
    def max_action(self) -> float: ...

    @property
    def actuated_dofs(self) -> Sequence[int]: ...

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]: ...

    def step(self, u: np.ndarray, /) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]: ...

    def close(self) -> None: ...


class Controller(Protocol):
    """A causal controller on the plant's measurements, called every plant step."""

    def reset(self, q_meas: np.ndarray) -> None: ...

    def act(self, q_meas: np.ndarray) -> np.ndarray: ...


class Policy(Protocol):
    """The trained agent as the deployed controller uses it: its deterministic action for an observation (SB3's
    ``predict``) and its action space (how many inputs it gives)."""

    @property
    def action_space(self) -> gym.spaces.Space[Any]: ...

    def predict(self, observation: np.ndarray, state: tuple[np.ndarray, ...] | None = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = False) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]: ...


class Agent(Policy, Protocol):
    """The agent as the loop trains it (SB3's ``OffPolicyAlgorithm``): ``learn`` on its env with callbacks,
    continued in a new env (``set_env``) with its decision count ``num_timesteps`` kept, the weights of a saved
    evaluation taken back (``set_parameters``), saved as a zip."""

    @property
    def num_timesteps(self) -> int: ...

    def learn(self, total_timesteps: int, callback: BaseCallback | None = None, log_interval: int = 4,
              tb_log_name: str = "run", reset_num_timesteps: bool = True, progress_bar: bool = False) -> object: ...

    def set_env(self, env: gym.Env, force_reset: bool = True) -> None: ...

    def set_parameters(self, load_path_or_dict: str, exact_match: bool = True,
                       device: torch.device | str = "auto") -> None: ...

    def save(self, path: str | Path, exclude: Iterable[str] | None = None,
             include: Iterable[str] | None = None) -> None: ...
