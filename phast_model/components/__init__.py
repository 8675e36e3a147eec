"""PHAST building blocks, each a small module behind one interface.

* :mod:`.observer`   -- causal velocity observer (FD + dilated TCN), Eq. 6-7; a training-only central difference.
* :mod:`.potentials` -- potential V(q): known, templates, neural, hybrid (Eq. 80-84).
* :mod:`.mass`       -- mass M: known M(q), constant diag + low rank (Woodbury, Eq. 79).
* :mod:`.damping`    -- damping D(q): Householder low rank with optional cap (Eq. 10-11).
* :mod:`.friction`   -- joint friction f(v): Coulomb / viscous / drag / Stribeck, backward-Euler step.
* :mod:`.features`   -- shared input features (angles as sin/cos).
"""

from .damping import Damping, HouseholderDamping, KnownDamping
from .features import coordinate_features, n_features
from .friction import JointFriction
from .mass import CholeskyMass, KnownMass, LowRankMass, Mass, TemplateMass
from .observer import CentralDifference, FDTCNObserver, finite_difference
from .potentials import (
    HybridPotential,
    KnownPotential,
    NeuralPotential,
    Potential,
    TemplatePotential,
    make_template,
)

__all__ = [
    "Damping", "HouseholderDamping", "KnownDamping", "coordinate_features", "n_features", "KnownMass", "LowRankMass",
    "TemplateMass", "CholeskyMass", "CentralDifference",
    "Mass", "FDTCNObserver", "finite_difference", "HybridPotential", "KnownPotential", "NeuralPotential", "Potential",
    "TemplatePotential", "make_template", "JointFriction",
]
