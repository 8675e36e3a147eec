"""The outputs of a loop run (``phast-rl``) and the deployed controller read back from them.

A run writes ``summary.json``, learning curves (``curves.json``, ``curves.png``), the agent as an SB3 zip
(``policy.zip``, opened by ``SAC.load``), the world model as a run directory (``model/``, opened by
:func:`phast_model.api.load_run`), every plant episode used for learning (``recordings.npz``, the ``phast-train
--recordings`` format) and the loop's configuration (``config.json``).  Every file is written to a temporary name and
renamed.  :func:`load_controller` rebuilds the controller the run deployed (the agent and the hold of its learned
model) from those files, to run it on a machine without the loop (``phast-rl --deploy``)."""

from __future__ import annotations

import os
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.env import parse_actuated_dofs
from phast_gym.fileio import atomic_write_json

from ..control.mppi import MPPISpec
from .hold import HoldConfig, HybridPolicy
from .loop import AgentSpec, FitSpec, LoopConfig, LoopResult, algo_class, deployed_policy
from .plant import PlantSpec, Task, plant_system
from .types import Agent


def learning_curves(result: LoopResult) -> dict[str, Any]:
    """Per iteration: plant seconds used, the share of its plant episodes that passed the quiet criterion (and the angle
    only), the world-model fit's validation RMSE; the agent's world-model evaluation returns against its cumulative
    decisions."""
    its = result.iterations
    steps = [t for it in its for t in it.world_eval_timesteps]  # the agent's num_timesteps: cumulative over iterations
    returns = [r for it in its for r in it.world_eval_returns]
    return {
        "iteration": [it.iteration for it in its],
        "plant_seconds": [it.plant_seconds for it in its],
        "plant_success": [float(np.mean(it.plant_success)) if it.plant_success else None for it in its],
        "plant_success_angle_only": [float(np.mean(it.plant_success_angle_only)) if it.plant_success else None
                                     for it in its],
        "fit_val_rmse": [it.fit_val_rmse for it in its],
        "agent_decisions": [it.agent_decisions for it in its],
        "world_eval_decisions": steps,
        "world_eval_return": returns,
        "final_success": None if result.evaluation is None else result.evaluation.success,
    }


def plot_learning_curves(curves: dict[str, Any], path: Path) -> None:
    """Two panels: plant success per iteration against plant seconds; the world-model evaluation return."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    xs = [s for s, v in zip(curves["plant_seconds"], curves["plant_success"]) if v is not None]
    a.plot(xs, [v for v in curves["plant_success"] if v is not None], "o-", label="quiet criterion")
    a.plot(xs, [v for v in curves["plant_success_angle_only"] if v is not None], "s--", label="angle only")
    a.set_xlabel("plant seconds used for learning")
    a.set_ylabel("success of the iteration's plant episodes")
    a.set_ylim(-0.05, 1.05)
    final = curves["final_success"]
    a.set_title("no plant evaluation (offline)" if final is None else f"final evaluation: {final:.2f} (quiet)",
                fontsize=9)
    a.legend(fontsize=8)
    a.grid(alpha=0.3)
    b.plot(curves["world_eval_decisions"], curves["world_eval_return"], "o-", ms=3)
    b.set_xlabel("agent decisions (cumulative)")
    b.set_ylabel("mean return in the world model (SB3 EvalCallback)")
    b.grid(alpha=0.3)
    fig.tight_layout()
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)


def save_agent(agent: Agent, path: Path) -> Path:
    """The agent as an SB3 zip (no replay buffer), written to a temporary name and renamed."""
    tmp = path.with_name(path.stem + ".tmp.zip")
    agent.save(tmp)
    os.replace(tmp, path)
    return path


def save_recordings(recordings: dict[str, Any], out: Path) -> Path:
    """``out/recordings.npz`` (the ``phast-train --recordings`` format), written to a temporary name and renamed."""
    tmp = out / "recordings.tmp.npz"
    np.savez(tmp, **recordings)
    return tmp.replace(out / "recordings.npz")


def write_outputs(result: LoopResult, out: Path, extra: dict[str, Any]) -> dict[str, Path]:
    """Write every output of the run into ``out``; ``extra`` is merged into summary.json (the config, the command)."""
    from ..train.checkpoint import save_run

    paths: dict[str, Path] = {}
    if result.agent is not None:  # the planner has no weights: the model and config.json rebuild it
        paths["policy"] = save_agent(result.agent, out / "policy.zip")
    save_run(result.model, out / "model")
    paths["model"] = out / "model"
    paths["recordings"] = save_recordings(result.recordings, out)
    curves = learning_curves(result)
    paths["curves_json"] = atomic_write_json(out / "curves.json", curves)
    plot_learning_curves(curves, out / "curves.png")
    paths["curves_png"] = out / "curves.png"
    if result.config is not None:
        paths["config"] = atomic_write_json(out / "config.json", asdict(result.config))
    paths["summary"] = atomic_write_json(out / "summary.json", {**result.summary(), **extra})
    return paths


#: the parts of a :class:`LoopConfig` that are dataclasses of their own
CONFIG_PARTS: dict[str, type] = {"plant": PlantSpec, "task": Task, "fit": FitSpec, "agent": AgentSpec,
                                 "hold": HoldConfig, "planner": MPPISpec}


def _part(cls: type, d: object, where: str) -> Any:
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected an object, got {type(d).__name__}")
    unknown = sorted(set(d) - {f.name for f in fields(cls)})
    if unknown:
        raise ValueError(f"{where}: unknown keys {unknown}")
    kw = {k: tuple(v) if isinstance(v, list) and cls in (AgentSpec, FitSpec) else v for k, v in d.items()}
    return cls(**kw)


def config_from_dict(d: dict[str, Any], where: str = "config.json") -> LoopConfig:
    """The :class:`LoopConfig` written as ``config.json`` (``dataclasses.asdict``); ValueError naming a bad key."""
    parts = {k: _part(cls, d[k], f"{where} '{k}'") for k, cls in CONFIG_PARTS.items() if k in d}
    return _part(LoopConfig, {**d, **parts}, where)


def load_config(run_dir: str | Path) -> LoopConfig:
    """The loop configuration of the ``phast-rl`` run in ``run_dir``."""
    import json

    path = Path(run_dir) / "config.json"
    if not path.is_file():
        raise ValueError(f"{run_dir}: no config.json (not a phast-rl run directory, or one written before it existed)")
    try:
        d = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    return config_from_dict(d, str(path))


def load_controller(run_dir: str | Path) -> HybridPolicy:
    """The controller the run in ``run_dir`` deployed: its agent (``policy.zip``; the planner of an ``--agent mpc``
    run: its config) and the hold built from its world model (``model/``) as in the loop.  ``reset(q)`` it with the
    first measurement, then ``act(q)`` every plant step of the run's ``dt`` (``load_config(run_dir).plant.dt``)."""
    from ..api import load_run

    run = Path(run_dir)
    cfg = load_config(run)
    agent = None
    if cfg.agent_kind != "mpc":
        if not (run / "policy.zip").is_file():
            raise ValueError(f"{run_dir}: no policy.zip")
        agent = algo_class(cfg.agent.algo).load(run / "policy.zip", device="cpu")
    model = load_run(run / "model")
    system = plant_system(replace(cfg.plant, machine=None))
    actuated = list(parse_actuated_dofs(cfg.plant.env_kwargs.get("actuated_dofs"), system.n))
    policy, _ = deployed_policy(cfg, agent, model, system, actuated, cfg.task.target(system))
    return policy
