"""Open-loop CEM on the true windy cart-pole: how close to upright can any held-force sequence (|u| <= UMAX) bring
the pole within T seconds from hanging at rest?  Batched RK4 on the system's own rhs."""
import math, sys, numpy as np
from phast_model.rl.plant import PlantSpec, plant_system
UMAX, T = float(sys.argv[1]), float(sys.argv[2])
sysm = plant_system(PlantSpec("PHAST/WindyCartPole-v0", {"actuated_dofs": [0]}))
dt, sub = 0.01, sysm.substeps
h = dt / sub
def f(x, u):
    q, p = (x[:, 0], x[:, 1]), (x[:, 2], x[:, 3])
    dq, dp = sysm.rhs(q, p, (u, np.zeros_like(u)))
    return np.stack([dq[0], dq[1], dp[0], dp[1]], 1)
def rollout(U):  # U (B, K) held 5 steps each
    B, K = U.shape
    x = np.zeros((B, 4)); best = np.full(B, 9.0)
    for k in range(K):
        u = U[:, k]
        for _ in range(5 * sub):
            k1 = f(x, u); k2 = f(x + h / 2 * k1, u); k3 = f(x + h / 2 * k2, u); k4 = f(x + h * k3, u)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        err = np.abs((x[:, 1] - math.pi + math.pi) % (2 * math.pi) - math.pi)
        best = np.minimum(best, err)
    return best
K = int(T / 0.05); rng = np.random.default_rng(0)
mu, sd = np.zeros(K), np.full(K, UMAX)
for it in range(int(sys.argv[3]) if len(sys.argv) > 3 else 20):
    U = np.clip(mu + sd * rng.standard_normal((200, K)), -UMAX, UMAX)
    U[0] = np.clip(mu, -UMAX, UMAX)
    c = rollout(U); el = U[np.argsort(c)[:20]]
    mu, sd = el.mean(0), el.std(0) + 0.05 * UMAX
    print(it, "best min angle-to-upright", round(float(c.min()), 3), flush=True)
