"""Module paths from before the package layout (``phast_model.model``, ``phast_model.training``, ...) keep importing.

The loose top-level modules moved into ``world/``, ``train/`` and ``rig/``; the flat modules of ``mismatch/`` into
its stage folders (``vocabulary/``, ``fitting/``, ``friction/``) and the shared ``rigs/`` layer.  A meta-path finder maps each old
dotted path to its new module (the same module object, so classes and functions are identical) and warns once
with a ``DeprecationWarning`` naming the new path.  ``phast_model.rig`` became a package that re-exports its old
names, so it needs no entry here.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from types import ModuleType

#: old dotted path -> new dotted path
MOVED: dict[str, str] = {
    "phast_model.model": "phast_model.world.model",
    "phast_model.config": "phast_model.world.config",
    "phast_model.core": "phast_model.world.core",
    "phast_model.fullstate": "phast_model.world.fullstate",
    "phast_model.interfaces": "phast_model.world.interfaces",
    "phast_model.rollout": "phast_model.world.rollout",
    "phast_model.data_init": "phast_model.world.data_init",
    "phast_model.regimes": "phast_model.world.regimes",
    "phast_model.envinfo": "phast_model.world.envinfo",
    "phast_model.world_env": "phast_model.world.gym_env",
    "phast_model.training": "phast_model.train.fit",
    "phast_model.checkpoint": "phast_model.train.checkpoint",
    "phast_model.runs": "phast_model.train.runs",
    "phast_model.metrics": "phast_model.train.metrics",
    "phast_model.plots": "phast_model.train.plots",
    "phast_model.provenance": "phast_model.train.provenance",
    "phast_model.rig_run": "phast_model.rig.run",
    "phast_model.rig_plots": "phast_model.rig.plots",
    "phast_model.mismatch.simulators": "phast_model.rigs.simulators",
    "phast_model.mismatch.recordings": "phast_model.rigs.recordings",
    "phast_model.mismatch.shooting": "phast_model.rigs.shooting",
    "phast_model.mismatch.registry": "phast_model.mismatch.vocabulary.registry",
    "phast_model.mismatch.terms": "phast_model.mismatch.vocabulary.terms",
    "phast_model.mismatch.candidates": "phast_model.mismatch.vocabulary.candidates",
    "phast_model.mismatch.screening": "phast_model.mismatch.vocabulary.screening",
    "phast_model.mismatch.problem": "phast_model.mismatch.fitting.problem",
    "phast_model.mismatch.linear": "phast_model.mismatch.fitting.linear",
    "phast_model.mismatch.laws": "phast_model.mismatch.friction.laws",
    "phast_model.mismatch.lawselect": "phast_model.mismatch.friction.lawselect",
    "phast_model.mismatch.passivity": "phast_model.mismatch.friction.passivity",
    "phast_model.mismatch.friction_plots": "phast_model.mismatch.friction.plots",
    "phast_model.mismatch.weakid": "phast_model.mismatch.friction.weakid",
    "phast_model.mismatch.weakform": "phast_model.rigs.weakform",
    "phast_model.mismatch.frictioncurve": "phast_model.rigs.frictioncurve",
}


class MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves an old module path to the module it moved to."""

    def find_spec(self, fullname: str, path: object = None, target: object = None) -> importlib.machinery.ModuleSpec | None:
        if fullname not in MOVED:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        new = MOVED[spec.name]
        warnings.warn(f"{spec.name} moved to {new}; import it from there", DeprecationWarning, stacklevel=3)
        return importlib.import_module(new)

    def exec_module(self, module: ModuleType) -> None:
        """The module is the already-executed new one."""


def install() -> None:
    """Put the finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, MovedModuleFinder) for f in sys.meta_path):
        sys.meta_path.append(MovedModuleFinder())
