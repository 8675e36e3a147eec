"""The vocabulary: which physics the tool can name, and the candidates it screens.

* :mod:`.registry`: one class per term kind (component, basis, expression, sign rule, candidate scale, velocity grid);
  :func:`~.registry.register` adds a kind from anywhere;
* :mod:`.terms`: :class:`~.terms.Term` (a kind on one coordinate with its coefficient) and
  :class:`~.terms.AugmentedSystem` (the simulator plus named terms, a port-Hamiltonian model again);
* :mod:`.candidates`: a candidate term or parameter change, and the model family they are fitted in.

The first stage of the tool: it imports no other stage (the selection stage screens its candidates on the prepared
problem, :mod:`..selection.screening`).
"""

from .registry import VOCABULARY, TermKind, register
from .terms import AugmentedSystem, Term

__all__ = ["VOCABULARY", "AugmentedSystem", "Term", "TermKind", "register"]
