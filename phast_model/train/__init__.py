"""Training and runs: the training loop (``fit``), checkpoints, ``phast-train``'s run pipeline, metrics, plots and
provenance (the commit a result was measured at)."""
