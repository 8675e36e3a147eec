"""Information floor of the next-step MSE (paper Eq. 90): the part of it no causal model can avoid.

The next-step MSE averages over t = 0..T-2, so it includes the prediction of q_1 from q_0 alone.  Every env
draws q_0 and p_0 independently (``System.sample_initial``), so the best first prediction is E[q_1 | q_0] and

    floor = E_{q_0}[ Var(q_1 | q_0) ] / (T - 1)      (averaged over coordinates, like ``mse``).

``test_floor_mse`` scores that best first prediction on the test split's own q_1 instead (the same in expectation).

``benchmarks/bench_first_step_floor.py`` tabulates it for the next-step rows of paper Table 4.
"""

from __future__ import annotations

import numpy as np

from phast_gym import make_env_system, resolve_env_id
from phast_gym.datasets import make_splits
from phast_gym.integrate import simulate

#: the envs whose paper Table 4 metric is the next-step MSE
NEXT_STEP_ENVS = ("PHAST/RLCCircuit-v0", "PHAST/LennardJones3-v0", "PHAST/HeatExchange-v0", "PHAST/NBody3-v0",
                  "PHAST/PredatorPrey-v0")


def first_step_floor(env_id: str, n_train: int = 200, n_val: int = 50, n_test: int = 50, T: int = 200,
                     data_seed: int = 42, draws: int = 256, seed: int = 0) -> dict[str, float | int | str]:
    """Floor of the t = 0 term of the next-step MSE on the test split of the benchmark's splits: ``draws``
    momenta p_0 from the env's own initial distribution for every test q_0, one step of the env's own
    integrator each (see the module docstring)."""
    env_id = resolve_env_id(env_id)
    if draws < 2:
        raise ValueError(f"draws must be >= 2, got {draws!r}")
    test = make_splits(env_id, n_train, n_val, n_test, T=T, seed=data_seed)["test"]
    system = make_env_system(env_id)
    n = system.n
    q0 = np.asarray(test.q_true[:, 0])  # (N, n)
    p0 = system.sample_initial(np.random.default_rng(seed), q0.shape[0] * draws)[:, n:]  # independent of q0
    x0 = np.concatenate([np.repeat(q0, draws, 0), p0], 1)
    q1 = simulate(system, x0, 1)[:, 1, :n].reshape(q0.shape[0], draws, n)
    var = q1.var(1, ddof=1).mean()  # E_q0 Var(q1 | q0), per coordinate
    # the best first prediction E[q_1 | q_0] scored on these test trajectories' own q_1 (the expectation above
    # varies with the sample of 200 test momenta by several per cent; this is what a model's t = 0 error is
    # comparable to)
    bayes = ((np.asarray(test.q[:, 1]) - q1.mean(1)) ** 2).mean()
    return {"env": env_id, "first_step_var": float(var), "floor_mse": float(var / (T - 1)),
            "test_floor_mse": float(bayes / (T - 1)), "T": T, "n_test": int(q0.shape[0]), "draws": int(draws)}
