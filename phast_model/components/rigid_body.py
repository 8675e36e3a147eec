"""PARTIAL for a MuJoCo model file: the rigid-body structure given, the bodies' inertial parameters learned.

A robot's V(q) and M(q) are fixed functions of its kinematics and linear in its bodies' inertial parameters (the
rigid-body regressor).  :class:`LearnedBodies` holds every body's mass, centre of mass (``ipos``) and principal
moments of inertia as learnable tensors that start at the file's values (masses and moments through a log, so they
stay positive); :class:`RigidBodyPotential` and :class:`RigidBodyMass` evaluate the model's own formulas
(:class:`phast_gym.systems.mjcf.MJCFSystem`, written once) with those tensors.  Both share one
:class:`LearnedBodies`: a body's mass moves V and M together, as it does on the machine.
"""

from __future__ import annotations

import copy
from typing import cast

import numpy as np
import torch
from torch import nn

from phast_gym.systems import TORCH, System, split, stack
from phast_gym.systems.mjcf import MJCFSystem, TreeState

from .features import inv_softplus
from .mass import Mass
from .potentials import Potential

#: a joint's armature, where the file gives none, starts at this share of its diagonal of M at the reference
#: configuration (measured on the real C.0 arm: 0.01 -> 0.249x the nominal held-out error, 0.05 -> 0.216x)
ARMATURE_START = 0.05


def _armature_start(system: MJCFSystem) -> np.ndarray:
    """Each joint's starting armature: the file's value, or ARMATURE_START of M_jj at qpos0 where the file has none
    (a softplus cannot start at 0, and a geared motor's rotor inertia is a few percent of what it drives)."""
    q0 = system.TREE.qpos0
    M = system.mass_matrix(tuple(np.array([x]) for x in q0))
    diag = np.array([float(np.ravel(M[j][j])[0]) for j in range(system.n)])
    given = np.asarray(system._armature, dtype=float)
    return np.where(given > 0, given, ARMATURE_START * diag)


class LearnedBodies(nn.Module):
    """Learnable inertial parameters of a model file's moving bodies (a body or moment at 0 in the file stays 0) and
    the joints' armature (a motor's rotor inertia)."""

    mass_on: torch.Tensor  # buffers: which masses / moments are free (non-zero in the file)
    inertia_on: torch.Tensor

    def __init__(self, system: System) -> None:
        super().__init__()
        if not isinstance(system, MJCFSystem):
            raise ValueError(f"rigid-body components need a MuJoCo model file as the rig, got {type(system).__name__}")
        self.base = system
        mass = np.asarray(system._mass, dtype=float)
        inertia = np.asarray(system._inertia, dtype=float)
        self.register_buffer("mass_on", torch.as_tensor(mass > 0))
        self.register_buffer("inertia_on", torch.as_tensor(inertia > 0))
        self.log_mass = nn.Parameter(torch.as_tensor(np.log(np.where(mass > 0, mass, 1.0))))
        self.ipos = nn.Parameter(torch.as_tensor(np.asarray(system._ipos, dtype=float)))
        self.log_inertia = nn.Parameter(torch.as_tensor(np.log(np.where(inertia > 0, inertia, 1.0))))
        self.raw_armature = nn.Parameter(inv_softplus(torch.as_tensor(_armature_start(system))))
        # (q, versions, system, tree state) of the last evaluation
        self._last: tuple[torch.Tensor, tuple[int | bool, ...], MJCFSystem, TreeState] | None = None

    def relative_parameters(self) -> list[nn.Parameter]:
        """Softplus coefficients that may start an order of magnitude from the machine's value (the rotor inertia):
        the rig trainer steps them like its friction coefficients."""
        return [self.raw_armature]

    def armature(self) -> torch.Tensor:
        """(n,) each joint's rotor inertia, softplus(raw) > 0."""
        return nn.functional.softplus(self.raw_armature)

    @torch.no_grad()
    def set_armature(self, values: torch.Tensor | np.ndarray, floor: float = 1e-9) -> None:
        """Set each joint's armature (clipped at ``floor``: a softplus never reaches 0)."""
        self.raw_armature.copy_(inv_softplus(torch.as_tensor(values, dtype=torch.float64).clamp_min(floor)))

    def state(self, q: torch.Tensor) -> tuple[MJCFSystem, TreeState]:
        """The system with the current parameters and its tree state at q (..., n), reused while neither q nor a
        parameter has changed: V, M^-1 p and dT/dq of one splitting step share one evaluation of the kinematics."""
        key = (q._version, self.log_mass._version, self.ipos._version, self.log_inertia._version,
               self.raw_armature._version, torch.is_grad_enabled())
        if self._last is not None and self._last[0] is q and self._last[1] == key:
            return self._last[2], self._last[3]
        s = self.system()
        st = s.tree_state(split(q))
        self._last = (q, key, s, st)
        return s, st

    def system(self) -> MJCFSystem:
        """The model file's system with the current (differentiable) parameters."""
        s = copy.copy(self.base)
        s._mass = torch.where(self.mass_on, torch.exp(self.log_mass), torch.zeros_like(self.log_mass))
        s._ipos = self.ipos * 1.0  # a tensor of the graph (not the Parameter itself)
        s._inertia = torch.where(self.inertia_on, torch.exp(self.log_inertia), torch.zeros_like(self.log_inertia))
        s._armature = self.armature()
        return s

    def values(self) -> dict[str, float]:
        """The current parameters in the file's names (``<body>.mass``, ``<body>.ipos_x``, ``<body>.inertia_y``)."""
        with torch.no_grad():
            s = self.system()
        out: dict[str, float] = {}
        for b, name in enumerate(self.base.TREE.body_names):
            out[f"{name}.mass"] = float(s._mass[b])
            for k, ax in enumerate("xyz"):
                out[f"{name}.ipos_{ax}"] = float(s._ipos[b, k])
                out[f"{name}.inertia_{ax}"] = float(s._inertia[b, k])
        for j, name in enumerate(self.base.TREE.joint_names):
            out[f"{name}.armature"] = float(s._armature[j])
        return out


class RigidBodyPotential(Potential):
    """V(q) of the model file (gravity and joint springs) with learned body parameters."""

    def __init__(self, bodies: LearnedBodies) -> None:
        super().__init__()
        self.bodies = bodies

    def energy(self, q: torch.Tensor) -> torch.Tensor:
        return self.bodies.system().potential(split(q), TORCH)

    def grad(self, q: torch.Tensor) -> torch.Tensor:
        s, st = self.bodies.state(q)
        return cast(torch.Tensor, s.grad_potential_at(st)).movedim(0, -1)


class RigidBodyMass(Mass):
    """M(q) of the model file (bodies and joint armature) with learned body parameters."""

    constant = False

    def __init__(self, bodies: LearnedBodies) -> None:
        super().__init__()
        self.bodies = bodies

    def matrix(self, q: torch.Tensor) -> torch.Tensor:
        _, st = self.bodies.state(q)
        return cast(torch.Tensor, st.M).movedim(0, -1).movedim(0, -1)

    def velocity(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        s, st = self.bodies.state(q)
        return stack(s.velocity_at(st, split(p)))

    def kinetic_dq(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        s, st = self.bodies.state(q)
        return cast(torch.Tensor, s.kinetic_dq_at(st, s.velocity_at(st, split(p)))).movedim(0, -1)
