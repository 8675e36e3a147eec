"""SAC swing-up on the TRUE cart-pole at the decision rate (the agent checked without PHAST): obs, reward weights and
episode length as phast-rl's world-model env.  UMAX=30 python sac_true_plant.py DECISIONS W_V W_X STEPS GAMMA
(the logs: 100 0.01 0.1 30000 0.99; 10 N stopped at 25,000 decisions, 30 N at 10,000)."""
import math, sys, time, json, numpy as np, torch, gymnasium as gym
torch.set_num_threads(1)
import os; UMAX = float(os.environ.get("UMAX", "10"))
from phast_model.rl.plant import PlantSpec, Task, make_plant, record_episode, quiet_metrics
from phast_model.rl.observation import ObsBuilder
from phast_model.rl.loop import make_agent, LoopConfig, AgentSpec
from phast_model.rl.hold import HybridPolicy
from phast_gym.systems.base import wrap

class TrueEnv(gym.Env):
    def __init__(self, decisions, wv, wx, seed, frames=3):
        self.plant = make_plant(PlantSpec("PHAST/WindyCartPole-v0", {"actuated_dofs": [0]}, max_action=UMAX))
        self.decisions, self.wv, self.wx = decisions, wv, wx
        self.b = ObsBuilder(frames, angle_dims=(1,))
        self.action_space = gym.spaces.Box(-1, 1, (1,), np.float32)
        self.observation_space = gym.spaces.Box(-1, 1, (self.b.size * 2,), np.float32)
        self.rng = np.random.default_rng(seed); self.task = Task("swingup")
    def reset(self, *, seed=None, options=None):
        x0 = self.task.start_states(self.plant.system, self.rng, 1)[0]
        q, info = self.plant.reset(seed=int(self.rng.integers(2**31)), options={"state": x0}); self.t = 0
        return self.b.reset(q), {}
    def step(self, a):
        u = np.clip(a, -1, 1) * UMAX
        for _ in range(5): q, _, _, _, info = self.plant.step(u)
        s = info["state"]; x, th = s[0], s[1]
        v = np.array(self.plant.system.velocity(tuple(s[:2]), tuple(s[2:])))
        e = wrap(th - math.pi)
        r = -(e**2 + self.wx * x**2 + self.wv * float(v @ v) + 0.001 * float(u @ u))
        self.t += 1
        term = abs(x) > 10
        if term: r = -50.0 * (self.decisions - self.t + 1)
        return self.b.push(q), float(r), bool(term), self.t >= self.decisions, {}

def main():
    decisions, wv, wx, steps, gamma = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5])
    env = TrueEnv(decisions, wv, wx, 0)
    cfg = LoopConfig()
    agent = make_agent(cfg, env)
    agent.gamma = gamma
    t0 = time.time()
    plant = make_plant(PlantSpec("PHAST/WindyCartPole-v0", {"actuated_dofs": [0]}, max_action=UMAX))
    q_star = np.array([0.0, math.pi])
    for chunk in range(steps // 5000):
        agent.learn(5000, reset_num_timesteps=False)
        pol = HybridPolicy(agent, 3, 5, UMAX, q_star, None, None, (1,))
        rng = np.random.default_rng(1)
        res = []
        for x0 in Task("swingup").start_states(plant.system, rng, 3):
            ep = record_episode(plant, pol, x0, 800, int(rng.integers(1000)), "evaluation")
            err = np.abs(wrap(ep.x[:, 1] - math.pi))
            res.append((round(float(err.min()), 2), round(float(err[-100:].max()), 2), round(float(np.abs(ep.x[:, 0]).max()), 1)))
        print(f"{(chunk+1)*5000} decisions {time.time()-t0:.0f}s: (min err, last-1s max err, max|x|) {res}", flush=True)
main()
