"""Import a script of this repository (``benchmarks/``, ``examples/``) by path, for the tests of its functions."""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_script(relpath: str, name: str | None = None) -> types.ModuleType:
    """A fresh module from ``ROOT / relpath``, registered in ``sys.modules`` under ``name`` (default: the file's stem)
    while it runs, where its dataclasses look their module up."""
    path = ROOT / relpath
    spec = importlib.util.spec_from_file_location(name or path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod
