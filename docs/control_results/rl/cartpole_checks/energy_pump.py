"""Bang-bang energy pumping on the true windy cart-pole from hanging at rest (noise-free): u = -UMAX sign(thetadot cos theta)
while the pole energy is below the upright's, for UMAX = 10 ... 50 N; prints how close to the upright the pole gets in 15 s
and when it first comes within 0.3 rad.  python energy_pump.py"""
import math, numpy as np
from phast_model.rl.plant import PlantSpec, make_plant

for umax in [10.0, 15.0, 20.0, 30.0, 50.0]:
    plant = make_plant(PlantSpec("PHAST/WindyCartPole-v0", {"actuated_dofs": [0]}, sigma=0.0, max_action=umax))
    q, info = plant.reset(seed=0, options={"state": np.array([0, 0.1, 0, 0.0])})
    s = info["state"]; best = 9; tup = None
    for t in range(1500):
        v = np.array(plant.system.velocity(tuple(s[:2]), tuple(s[2:])))
        th, w = s[1], v[1]
        E = 0.5 * w**2 + 9.81 * (1 - math.cos(th))
        u = -umax * np.sign(w * math.cos(th)) if E < 2 * 9.81 else -3 * s[0] - 3 * v[0]
        q, _, _, _, info = plant.step(np.array([u])); s = info["state"]
        err = abs((s[1] - math.pi + math.pi) % (2 * math.pi) - math.pi)
        if err < best: best = err
        if err < 0.3 and tup is None: tup = t * 0.01
    print(umax, "closest to upright", round(best, 3), "first within 0.3 rad at", tup, "x", round(s[0], 2))
