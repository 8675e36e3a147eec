"""Fit PHAST by the loop's rig path to random-input excitation of a plant (issue 55's checks, docs/control.md).

    [SIMKW=JSON] [REGIME=partial|known] python fit.py ENV ENV_KWARGS_JSON MAX_ACTION EPISODE_S OUT [EPISODES]

SIMKW: the description's parameters (default: none, the class's nominal ones); prints the fit's validation RMSE and
saves the model to OUT.
"""
import json
import os
import sys
import time

import torch

from phast_model.rl.loop import FitSpec, LoopConfig, _Data, collect_excitation, fit_world_model
from phast_model.rl.plant import PlantSpec, make_plant
from phast_model.train.checkpoint import save_run

torch.set_num_threads(1)
env, kw, ma, eps, out = sys.argv[1], json.loads(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), sys.argv[5]
episodes = int(sys.argv[6]) if len(sys.argv) > 6 else 1
fit_spec = FitSpec(None, json.loads(os.environ.get("SIMKW", "{}")), os.environ.get("REGIME", "partial"))
cfg = LoopConfig(fit=fit_spec, plant=PlantSpec(env, kw, max_action=ma), budget_s=60, episode_s=eps,
                 excitation_episodes=episodes)
plant = make_plant(cfg.plant)
t = time.time()
data = _Data(None, collect_excitation(cfg, plant, 0))
fit = fit_world_model(cfg, data.recordings(cfg, plant), None)
print("fit s", round(time.time() - t, 1), "val RMSE", fit.val_rmse)
save_run(fit.model, out)
