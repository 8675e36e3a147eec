"""The planner's controller time per plant step, traced against eager, in one run (issue 55: the controller must fit
in the plant's dt on one core).

For each plant: PHAST fitted to one 2.5-s excitation episode (``--epochs``), then ``phast-rl --agent mpc``'s deployed
controller (MPPI + the learned LQR hold and its UKF, :func:`phast_model.rl.planner.planner_policy`) run for ``--steps`` plant
steps from hanging, once with the model's steps traced (:mod:`phast_model.control.traced`) and once eager, on the
same plant seed.  Prints mean / p99 / max ms per step and the eager / traced ratio; ``--out`` writes the JSON.

    taskset -c 1 python benchmarks/planner_speed.py --out docs/control_results/rl_mpc/planner_speed.json
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

#: plant -> (env id, env kwargs, --max-action): the cases of benchmarks/control_mpc.py
PLANTS: dict[str, tuple[str, dict[str, Any], float]] = {
    "pendulum": ("PHAST/Pendulum-v0", {}, 10.0),
    "pilco": ("PHAST/WindyCartPole-v0", {"cart_mass": 0.5, "pole_mass": 0.5, "length": 0.6, "d_cart": 0.1, "d0": 0.0,
                                         "dd": 0.0, "actuated_dofs": [0]}, 10.0),
    "windy": ("PHAST/WindyCartPole-v0", {"actuated_dofs": [0]}, 30.0),
    "acrobot": ("PHAST/DoublePendulum-v0", {"actuated_dofs": [1]}, 10.0),
}


def controller_ms(plant_name: str, steps: int, epochs: int) -> dict[str, dict[str, float]]:
    """{"traced": ..., "eager": ...}: mean / p99 / max ms per plant step of the deployed planner on ``plant_name``."""
    import torch

    from phast_model.control.mppi import MPPISpec
    from phast_model.rl.hold import HoldConfig
    from phast_model.rl.loop import FitSpec, LoopConfig, _Data, collect_excitation, fit_world_model
    from phast_model.rl.planner import planner_policy
    from phast_model.rl.plant import PlantSpec, make_plant

    torch.set_num_threads(1)
    env_id, kwargs, max_action = PLANTS[plant_name]
    cfg = LoopConfig(plant=PlantSpec(env_id=env_id, env_kwargs=kwargs, max_action=max_action), episode_s=2.5,
                     excitation_episodes=1, fit=FitSpec(epochs=epochs))
    plant = make_plant(cfg.plant)
    data = _Data(None, collect_excitation(cfg, plant, 0))
    model = fit_world_model(cfg, data.recordings(cfg, plant), None).model
    q_star = cfg.task.target(plant.system)
    out = {}
    for name, traced in (("traced", True), ("eager", False)):
        hold = HoldConfig(kind="lqr", lqr_ukf_p_per_inertia=True, traced=traced)  # phast-rl's planner preset
        policy, _ = planner_policy(model, replace(MPPISpec(), traced=traced), q_star, cfg.plant, hold,
                                   list(plant.actuated_dofs))
        q, _ = plant.reset(seed=1, options={"state": np.zeros(2 * plant.n)})
        policy.reset(q)
        t = np.empty(steps)
        for k in range(steps):
            t0 = time.perf_counter()
            u = policy.act(q)
            t[k] = time.perf_counter() - t0
            q, *_ = plant.step(u)
        ms = t * 1e3
        out[name] = {"mean": round(float(ms.mean()), 3), "p99": round(float(np.percentile(ms, 99)), 3),
                     "max": round(float(ms.max()), 3)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plants", nargs="+", choices=sorted(PLANTS), default=list(PLANTS))
    ap.add_argument("--steps", type=int, default=1000, help="plant steps per controller (10 s at dt 0.01)")
    ap.add_argument("--epochs", type=int, default=10, help="the fit's epochs (the timing does not depend on them)")
    ap.add_argument("--out", default=None, help="write the results as JSON here")
    args = ap.parse_args()
    res: dict[str, Any] = {}
    for name in args.plants:
        r = controller_ms(name, args.steps, args.epochs)
        r["eager_over_traced"] = {k: round(r["eager"][k] / r["traced"][k], 2) for k in ("mean", "p99")}
        res[name] = r
        print(f"{name:9s} traced {r['traced']}  eager {r['eager']}  eager/traced {r['eager_over_traced']}",
              flush=True)
    if args.out:
        from phast_gym.fileio import atomic_write_json

        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_json(Path(args.out), res)


if __name__ == "__main__":
    main()
