"""SB3 SAC trained on the plant or inside a PHAST world model, compared with Energy-Casimir control (issue 29;
``benchmarks/control_sac.py``, docs/control.md section "SB3 SAC").  A study, not part of the product: the loop that
learns a policy from seconds of plant time is :mod:`phast_model.rl` (``phast-rl``).

* :mod:`.config`: the benchmark's options as one dataclass (:class:`.config.SacConfig`) and what follows from them;
* :mod:`.cli`: the command line (``benchmarks/control_sac.py``), the result tables;
* :mod:`.agents`: SAC on the agents' environments, trained with an SB3 callback (:class:`.agents.LearningCurve`) until
  the learning curve is flat or a fixed budget, the result row;
* :mod:`.rewards`: the per-step rewards (``zoo``, ``quiet``, ``precise``) and the quiet weight's bound at the upright;
* :mod:`.envs`: the training environments (decisions every ``repeat`` plant steps, start regimes, the world-model env
  with real burn-ins);
* :mod:`.evaluation`: the flatness rule, the metrics on the plant, the learning-curve figure;
* :mod:`.world_data`: a world model of the plant learned from driven, noisy recordings, and the real samples it cost
  (``benchmarks/sac_world_data.py``);
* :mod:`.summary`: result rows of several training seeds pooled into one table (``benchmarks/control_sac_summary.py``).

The policy observation (:mod:`phast_model.rl.observation`) and the mirror-equivariant SAC policy
(:mod:`phast_model.rl.mirror_policy`) are the loop's.
"""
