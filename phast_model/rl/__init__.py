"""Policies learned on the plant or inside a PHAST world model, compared with Energy-Casimir control
(``benchmarks/control_sac.py``, docs/control.md), and the model-based RL loop that learns them from seconds of plant
time (``phast-rl``, issue 40).

The loop (docs/control.md, section "Policies from seconds on the machine"):

* :mod:`.loop`: collect -> fit PHAST (rig path, warm-started) -> train an SB3 agent in the world model -> run on the
  plant -> repeat; :class:`.loop.LoopConfig`, :func:`.loop.run_loop`, :class:`.loop.LoopResult`;
* :mod:`.plant`: the plant, the task, episodes, plant-time accounting, the quiet criterion;
* :mod:`.sources`: a real machine behind a step function as the plant, recordings made before the loop;
* :mod:`.world_env`: the agent's env inside the learned model, started from recorded windows;
* :mod:`.hold`: the Energy-Casimir hold built from the learned model (a UKF on the learned core), the hybrid policy;
* :mod:`.loop_report`: summary.json, learning curves, policy.zip, the model and the recordings of a run.

The one-shot agents of issue 29:

* :mod:`.rewards`: the per-step rewards (``zoo``, ``quiet``, ``precise``) and the quiet weight's bound at the upright;
* :mod:`.envs`: the training environments (decisions every ``repeat`` plant steps, start regimes, the world-model env
  with real burn-ins) and the policy observation shared by training and evaluation;
* :mod:`.evaluation`: the flatness rule, the metrics on the plant, the learning-curve figure;
* :mod:`.sac`: SB3 SAC from the benchmark's options, its training loop and result row (stable-baselines3);
* :mod:`.world_data`: a world model of the plant learned from driven, noisy recordings, and the real samples it cost;
* :mod:`.summary`: result rows of several training seeds pooled into one table.

The mirror-equivariant SAC policy is :mod:`.mirror_policy`.
"""
