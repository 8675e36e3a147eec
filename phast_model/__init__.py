"""phast_model: the PHAST world model, baselines, benchmark harness, control and mismatch tools (torch)."""

__version__ = "0.1.0"
