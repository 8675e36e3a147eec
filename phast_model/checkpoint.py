"""Save / load PHAST runs: ``model.pt`` (state dict, loaded with ``weights_only=True``) + ``config.json``.

A missing, truncated, corrupted or foreign file raises ``ValueError`` naming the problem;
writes go to a temp file first and are moved into place with ``os.replace``.
"""

from __future__ import annotations

import io
import json
import pickle
import zipfile
from pathlib import Path
from typing import Any

import torch

from phast_gym.fileio import atomic_write_bytes
from phast_gym.fileio import atomic_write_json as _atomic_write_json

from .model import PHAST, PHASTConfig, build_from_config

FORMAT = "phast-run"
VERSION = 1
MODEL_FILE, CONFIG_FILE = "model.pt", "config.json"


def atomic_write_json(path: Path, obj: Any) -> None:
    """config.json / metrics.json writer: sorted keys, atomic."""
    _atomic_write_json(path, obj, indent=2, sort_keys=True)


def save_run(model: PHAST, run_dir: str | Path, extra: dict[str, Any] | None = None) -> Path:
    """Write ``model.pt`` and ``config.json`` (the model's :class:`PHASTConfig` plus ``extra``) to ``run_dir``."""
    run_dir = Path(run_dir)
    cfg = getattr(model, "config", None)
    if not isinstance(cfg, PHASTConfig):
        raise ValueError(f"save_run needs a PHAST model with a PHASTConfig, got {type(model).__name__}")
    buf = io.BytesIO()
    torch.save({k: v.detach().cpu() for k, v in model.state_dict().items()}, buf)
    atomic_write_bytes(run_dir / MODEL_FILE, buf.getvalue())
    dtype = str(next(model.parameters()).dtype).replace("torch.", "")
    atomic_write_json(run_dir / CONFIG_FILE, {"format": FORMAT, "version": VERSION, "model": cfg.to_dict(),
                                              "dtype": dtype, **(extra or {})})
    return run_dir


def read_config(run_dir: str | Path) -> dict[str, Any]:
    """The run's ``config.json`` after format checks."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.exists():
        raise ValueError(f"{run_dir} is not a PHAST run: {CONFIG_FILE} is missing")
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"corrupted {path}: {exc}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"{path} is not a PHAST run config (format {meta.get('format') if isinstance(meta, dict) else None!r})")
    if meta.get("version") != VERSION:
        raise ValueError(f"{path} has version {meta.get('version')!r}; this phast reads version {VERSION}")
    return meta


def load_state(path: str | Path) -> dict[str, torch.Tensor]:
    """A state dict saved by :func:`save_run` (``weights_only=True``), or ValueError."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"checkpoint {path} is missing")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, EOFError, pickle.UnpicklingError, zipfile.BadZipFile, OSError, ValueError, AttributeError) as exc:
        raise ValueError(f"corrupted or unreadable checkpoint {path}: {exc}") from None
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise ValueError(f"{path} is not a PHAST state dict")
    return state


def load_model(run_dir: str | Path) -> PHAST:
    """Rebuild the model of ``run_dir`` from ``config.json`` and load ``model.pt`` (strict)."""
    meta = read_config(run_dir)
    try:
        cfg = PHASTConfig.from_dict(meta["model"])
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{run_dir}/{CONFIG_FILE} has no valid model config: {exc}") from None
    model = build_from_config(cfg)
    if meta.get("dtype") == "float64":
        model = model.double()
    state = load_state(Path(run_dir) / MODEL_FILE)
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise ValueError(f"{run_dir}/{MODEL_FILE} does not match its config ({cfg.env_id}, {cfg.regime}): "
                         f"{str(exc).splitlines()[0]}") from None
    model.eval()
    return model
