"""Training and runs: the one epoch loop both trainers share (``loop``: NaN guard, checkpoints, resume, best-validation
weights, early stopping, schedule) with its objectives (``fit.NextStep`` for the envs,
``phast_model.train.rig_fit.Shooting`` for a rig's recordings), the optimizer's parameter groups (``groups``), the env
path's config (``config``) and trainer (``fit``), checkpoints, ``phast-train``'s run pipeline, metrics, plots and
provenance (the commit a result was measured at)."""
