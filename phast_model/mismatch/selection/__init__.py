"""The selection stage: which parameter changes and vocabulary terms the recordings need, by multiple shooting.

* :mod:`.screening`: :func:`~.screening.candidates`, every vocabulary term on every coordinate where it can act,
  scaled to that coordinate's force (the candidates the selection screens);
* :mod:`.search`: the state of one selection (:class:`~.search.Search`) and its result (:class:`~.search.Selection`);
* :mod:`.forward`: :func:`~.forward.select`, the forward selection by shooting on top of a full-rank calibration and
  its checks (pruning, equivalent parameter changes, two-fold validation, velocities, sharper edges, intervals);
* :mod:`.law_look`: the longer look at dissipation laws of equal evidence on one joint (windows
  :data:`~.law_look.LAW_LOOK` times the selection's).

The selection answers first (:class:`..explainers.ShootingExplainer`); the friction stage (:mod:`..friction`) may
challenge it.
"""

from .forward import INTERVALS, quantile95, select
from .screening import candidates
from .search import Selection

__all__ = ["INTERVALS", "Selection", "candidates", "quantile95", "select"]
