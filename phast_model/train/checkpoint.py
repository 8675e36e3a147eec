"""Save / load PHAST runs: ``model.pt`` (state dict, loaded with ``weights_only=True``) + ``config.json``.

A missing, truncated, corrupted or foreign file raises ``ValueError`` naming the problem;
writes go to a temp file first and are moved into place with ``os.replace``.
"""

from __future__ import annotations

import io
import json
import pickle
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from phast_gym.fileio import atomic_write_bytes, jsonable
from phast_gym.fileio import atomic_write_json as _atomic_write_json

from ..world.model import PHAST, PHASTConfig, build_from_config

FORMAT = "phast-run"
VERSION = 1
MODEL_FILE, CONFIG_FILE = "model.pt", "config.json"
#: key of the run identity (config.json's content as UTF-8 JSON bytes) inside model.pt
IDENTITY_KEY = "_phast_run_identity"


def atomic_write_json(path: Path, obj: object) -> None:
    """config.json / metrics.json writer: sorted keys, atomic."""
    _atomic_write_json(path, obj, indent=2, sort_keys=True)


def atomic_torch_save(obj: object, path: str | Path) -> Path:
    """``torch.save(obj)`` serialized in memory, then written with :func:`phast_gym.fileio.atomic_write_bytes`:
    a reader (or a killed writer) never leaves a partial file at ``path``."""
    buf = io.BytesIO()
    torch.save(obj, buf)
    return atomic_write_bytes(path, buf.getvalue())


def save_run(model: PHAST, run_dir: str | Path, extra: Mapping[str, object] | None = None) -> Path:
    """Write ``model.pt`` and ``config.json`` (the model's :class:`PHASTConfig` plus ``extra``) to ``run_dir``."""
    run_dir = Path(run_dir)
    cfg = getattr(model, "config", None)
    if not isinstance(cfg, PHASTConfig):
        raise ValueError(f"save_run needs a PHAST model with a PHASTConfig, got {type(model).__name__}")
    dtype = str(next(model.parameters()).dtype).replace("torch.", "")
    meta = jsonable({"format": FORMAT, "version": VERSION, "model": cfg.to_dict(), "dtype": dtype, **(extra or {})})
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    # the run's identity travels inside model.pt (a uint8 tensor: still weights_only), so a model.pt of another
    # run (another env, regime, data or training config) is refused by load_model even when the shapes match
    state[IDENTITY_KEY] = torch.frombuffer(bytearray(_identity_json(meta).encode()), dtype=torch.uint8)
    atomic_torch_save(state, run_dir / MODEL_FILE)
    atomic_write_json(run_dir / CONFIG_FILE, meta)
    return run_dir


def _identity(meta: Mapping[str, object]) -> dict[str, object]:
    """What identifies a run in its config.json: everything but the format fields."""
    return {k: v for k, v in meta.items() if k not in ("format", "version")}


def _identity_json(meta: Mapping[str, object]) -> str:
    return json.dumps(_identity(meta), sort_keys=True, default=str)


#: fields compared (and so named) first: the ones a person recognizes
_FIRST = ("env_id", "regime", "model", "data", "train")


def first_difference(stored: object, wanted: object, prefix: str = "") -> tuple[str, object, object] | None:
    """(dotted field, stored value, wanted value) of the first field where two JSON values differ (env, regime,
    model, data and training fields first), else None."""
    if isinstance(stored, dict) and isinstance(wanted, dict):
        for k in sorted(set(stored) | set(wanted),
                        key=lambda k: (k not in _FIRST, _FIRST.index(k) if k in _FIRST else 0, k)):
            d = first_difference(stored.get(k, "<absent>"), wanted.get(k, "<absent>"), f"{prefix}{k}.")
            if d is not None:
                return d
        return None
    return None if stored == wanted else (prefix.rstrip("."), stored, wanted)


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
        raise ValueError(f"{path} is not a PHAST run config "
                         f"(format {meta.get('format') if isinstance(meta, dict) else None!r})")
    if meta.get("version") != VERSION:
        raise ValueError(f"{path} has version {meta.get('version')!r}; this phast reads version {VERSION}")
    return meta


def torch_load(path: str | Path, what: str = "checkpoint") -> Any:
    """``torch.load(path, weights_only=True)`` on CPU, or ValueError with a reason a person can act on
    (missing, empty, truncated, not a torch file, unreadable)."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{what} {path} is missing")
    try:
        size = path.stat().st_size
        if size == 0:
            raise ValueError(f"corrupted or unreadable {what} {path}: the file is empty "
                             "(0 bytes; an interrupted write?)")
        if not zipfile.is_zipfile(path):
            raise ValueError(f"corrupted or unreadable {what} {path}: truncated or not a torch checkpoint "
                             f"({size} bytes, no zip directory)")
        return torch.load(path, map_location="cpu", weights_only=True)
    except ValueError as exc:
        if str(exc).startswith("corrupted or unreadable"):
            raise
        reason: Exception = exc
    except (RuntimeError, EOFError, pickle.UnpicklingError, zipfile.BadZipFile, OSError, AttributeError,
            KeyError) as exc:
        reason = exc
    text = getattr(reason, "strerror", None) or (str(reason).splitlines() or [""])[0]
    raise ValueError(f"corrupted or unreadable {what} {path}: {type(reason).__name__}"
                     f"{': ' + text if text else ' (truncated file)'}") from None


def load_state(path: str | Path) -> dict[str, torch.Tensor]:
    """A state dict saved by :func:`save_run` (``weights_only=True``), or ValueError."""
    path = Path(path)
    state = torch_load(path)
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
    ident = state.pop(IDENTITY_KEY, None)  # a model.pt of the format's first release has none: loaded unchecked
    if ident is not None:
        try:
            stored = json.loads(bytes(ident.to(torch.uint8).tolist()).decode())
        except (ValueError, UnicodeDecodeError):
            raise ValueError(f"{run_dir}/{MODEL_FILE} has a corrupted run identity") from None
        diff = first_difference(stored, json.loads(_identity_json(meta)))
        if diff is not None:
            field_, old, new = diff
            raise ValueError(f"{run_dir}/{MODEL_FILE} does not belong to {run_dir}/{CONFIG_FILE}: it was saved for "
                             f"{field_}={old!r}, {CONFIG_FILE} says {field_}={new!r}")
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise ValueError(f"{run_dir}/{MODEL_FILE} does not match its config ({cfg.env_id}, {cfg.regime}): "
                         f"{str(exc).splitlines()[0]}") from None
    model.eval()
    return model
