"""World-model error along a phast-rl run's plant episodes, against the same rollout with the TRUE plant physics from
the same inferred initial state (last measured q, the model observer's qdot): what the learned model adds to the
error of starting from a noisy window.  Pole angle, RMS over starts every 0.25 s, at 0.5 s and 1 s."""
import sys, math, numpy as np, torch
torch.set_num_threads(1)
from phast_model.api import load_run
from phast_gym.systems.base import wrap
from phast_model.rl.plant import PlantSpec, make_plant
run, umax = sys.argv[1], float(sys.argv[2])
model = load_run(f"{run}/model"); model.eval()
r = np.load(f"{run}/recordings.npz"); q, u = r["q"], r["u"]
W = model.observer.window; dtype = next(model.parameters()).dtype
plant = make_plant(PlantSpec("PHAST/WindyCartPole-v0", {"actuated_dofs": [0]}, sigma=0.0, max_action=umax))
tot = {"pm": [], "tr": []}
for i in range(len(q)):
    em, et = {10: [], 20: []}, {10: [], 20: []}
    for t0 in range(W, q.shape[1] - 20, 5):
        hist = torch.as_tensor(q[i, t0 - W:t0][None], dtype=dtype)
        with torch.no_grad(): v0 = model.observer(hist)[0, -1].double().numpy()
        q0 = q[i, t0 - 1]
        p0 = np.array(plant.system.momentum(tuple(q0), tuple(v0)), float)
        plant.reset(seed=0, options={"state": np.concatenate([q0, p0])})
        for h in range(20):
            uf = torch.zeros(1, model.m, dtype=dtype); uf[0, 0] = float(u[i, t0 - 1 + h, 0])
            with torch.no_grad(): q1 = model.predict_next(hist, uf)
            hist = torch.cat([hist, q1[:, None]], 1)[:, -W:]
            for _ in range(5): _, _, _, _, info = plant.step(np.array([float(u[i, t0 - 1 + h, 0])]))
            if h + 1 in em:
                em[h + 1].append(abs(float(wrap(q1[0, 1].item() - q[i, t0 + h, 1]))))
                et[h + 1].append(abs(float(wrap(info["state"][1] - q[i, t0 + h, 1]))))
    rm = lambda a: float(np.sqrt(np.mean(np.square(a))))
    e = np.abs(wrap(q[i, :, 1] - math.pi))
    print(i, "excitation" if i < 2 else "policy", "pole err @0.5s PHAST %.3f true %.3f | @1s PHAST %.3f true %.3f" % (
        rm(em[10]), rm(et[10]), rm(em[20]), rm(et[20])), "| closest to upright %.2f" % e.min(), flush=True)
