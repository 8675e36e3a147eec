"""Policies learned on the plant or inside a PHAST world model, compared with Energy-Casimir control
(``benchmarks/control_sac.py``, docs/control.md).

* :mod:`.rewards`: the per-step rewards (``zoo``, ``quiet``, ``precise``) and the quiet weight's bound at the upright;
* :mod:`.envs`: the training environments (decisions every ``repeat`` plant steps, start regimes, the world-model env
  with real burn-ins) and the policy observation shared by training and evaluation;
* :mod:`.evaluation`: the flatness rule, the metrics on the plant, the learning-curve figure;
* :mod:`.sac`: SB3 SAC from the benchmark's options, its training loop and result row (stable-baselines3);
* :mod:`.world_data`: a world model of the plant learned from driven, noisy recordings, and the real samples it cost;
* :mod:`.summary`: result rows of several training seeds pooled into one table.

The mirror-equivariant SAC policy is :mod:`phast_model.world.mirror_policy`.
"""
