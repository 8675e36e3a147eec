"""Thin command-line front ends over the phast_model Python API (console scripts in pyproject.toml)."""
