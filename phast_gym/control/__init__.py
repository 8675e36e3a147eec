"""Energy-Casimir control of phast_gym plants through the env step API (numpy only).

* :class:`EnergyCasimirController` / :class:`EnergyCasimirWrapper`: paper Eq. 28-31;
* port (velocity) estimators behind one interface, built by name with :func:`make_estimator`
  (``oracle``, ``fd``, ``map``, ``ukf``, with ``ekf`` a deprecated alias of ``ukf``; packages above this one register
  their own, see :func:`register_estimator_provider`);
* :mod:`.evaluation`: the closed-loop protocol of paper Sec. 4.2 (start regimes, metrics);
* :mod:`.report`: its tables and plots.
"""

from .controller import XI_FEEDBACK, EnergyCasimirController, EnergyCasimirWrapper, validate_gains
from .estimators import (
    ESTIMATORS,
    FiniteDifferenceEstimator,
    MAPSmootherEstimator,
    OracleEstimator,
    PortEstimator,
    UKFEstimator,
    UnscentedParams,
    estimator_names,
    make_estimator,
    map_smoother_weights,
    register_estimator,
    register_estimator_provider,
    resolve_estimator_name,
)
from .evaluation import (
    START_REGIMES,
    ControlProtocol,
    ControlRow,
    Episode,
    evaluate_estimators,
    make_control_env,
    run_episode,
    sample_start_states,
    start_states,
)

__all__ = [
    "XI_FEEDBACK", "EnergyCasimirController", "EnergyCasimirWrapper", "validate_gains", "ESTIMATORS", "PortEstimator",
    "OracleEstimator", "FiniteDifferenceEstimator", "MAPSmootherEstimator", "UKFEstimator", "UnscentedParams",
    "estimator_names", "make_estimator", "map_smoother_weights", "register_estimator", "register_estimator_provider",
    "resolve_estimator_name",
    "START_REGIMES", "ControlProtocol", "ControlRow", "Episode",
    "evaluate_estimators", "make_control_env", "run_episode", "sample_start_states", "start_states",
]
