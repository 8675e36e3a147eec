"""The deployed planner (or, with TASK=upright, the hold alone) on a plant with a saved model: 3 episodes, the quiet
criterion, the first time within 0.3 rad, the controller's ms (issue 55's checks, docs/control.md).

    [HOLD=HoldConfig JSON] [TASK=swingup|upright] python try_planner.py ENV ENV_KWARGS_JSON MAX_ACTION MODEL SECONDS \
        [MPPISpec JSON]
"""
import json
import os
import sys
import time

import numpy as np
import torch

from phast_gym.systems.base import wrap
from phast_model.api import load_run
from phast_model.control.mppi import MPPISpec
from phast_model.rl.hold import HoldConfig
from phast_model.rl.loop import LoopConfig, act_ms, run_policy
from phast_model.rl.planner import planner_policy
from phast_model.rl.plant import PlantSpec, Task, make_plant, quiet_metrics, quiet_u_tol

torch.set_num_threads(1)
env, kw, ma, model_dir, secs = sys.argv[1], json.loads(sys.argv[2]), float(sys.argv[3]), sys.argv[4], float(sys.argv[5])
spec = MPPISpec(**(json.loads(sys.argv[6]) if len(sys.argv) > 6 else {}))
ps = PlantSpec(env, kw, max_action=ma)
task = Task(os.environ.get("TASK", "swingup"), u_tol=quiet_u_tol(ps))
print("u_tol", task.u_tol)
cfg = LoopConfig(plant=ps, task=task)
plant = make_plant(ps)
q_star = task.target(plant.system)
hold = HoldConfig(**json.loads(os.environ.get("HOLD", "{}")))
pol, _ = planner_policy(load_run(model_dir), spec, q_star, ps, hold, list(plant.actuated_dofs))
t = time.time()
eps = run_policy(cfg, plant, pol, 3, int(secs / ps.dt), 123, "evaluation")
dims = list(plant.system.angle_dims)
for e in eps:
    m = quiet_metrics(e, q_star, dims, task)
    err = np.abs(wrap(e.x[:, dims] - q_star[dims])).max(1)
    hit = float(np.argmax(err < 0.3) * ps.dt) if (err < 0.3).any() else None
    print(m, "first < 0.3 rad at", hit, "handoffs", e.handoffs)
print("ms", act_ms(eps), "wall", round(time.time() - t, 1), "H", pol.mppi.horizon)
