"""The model-based RL loop that learns a policy from seconds of plant time (``phast-rl``; docs/control.md,
section "Policies from seconds on the machine"):

* :mod:`.loop`: collect -> fit PHAST (rig path, warm-started) -> train an SB3 agent in the world model -> run on the
  plant -> repeat; :class:`.loop.LoopConfig`, :func:`.loop.run_loop`, :class:`.loop.LoopResult`;
* :mod:`.plant`: the plant, the task, episodes, plant-time accounting, the quiet criterion;
* :mod:`.sources`: a real machine behind a step function as the plant, recordings made before the loop;
* :mod:`.world_env`: the agent's env inside the learned model, started from recorded windows;
* :mod:`.observation`: the agent's observation ((sin q, cos q) of the last measurements);
* :mod:`.mirror_policy`: the reflection-equivariant SAC policy;
* :mod:`.planner`: the planning agent (``--agent mpc``): MPPI through the learned core
  (:mod:`phast_model.control.mppi`), sliced over the plant steps, with the hold near the target;
* :mod:`.hold`: the Energy-Casimir hold built from the learned model (a UKF on the learned core), the hybrid policy;
* :mod:`.loop_report`: summary.json, learning curves, policy.zip, the model and the recordings of a run;
* :mod:`.descriptions`: the rig descriptions and option presets of the plants;
* :mod:`.types`: the protocols of the loop's plant, controller and agent.

SAC trained on the plant or in a PHAST world model and compared with Energy-Casimir control is a
benchmark: ``benchmarks/sac`` (``benchmarks/control_sac.py``).
"""
