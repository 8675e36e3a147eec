"""phast_model: the PHAST world model, baselines, benchmark harness, control and mismatch tools (torch)."""

from phast_gym.control.estimators import register_estimator_provider

__version__ = "0.1.0"

#: port estimators that importing :mod:`phast_model.control` registers (torch-based).  Declared here, where
#: importing is cheap, so that ``phast_gym.control.estimator_names()`` lists them and ``make_estimator``
#: imports :mod:`phast_model.control` on first use: phast_gym itself never names this package.
CONTROL_ESTIMATORS = ("tcn", "tcn-uniform", "tcn-cond", "phast-observer", "phast-model", "phast-ukf")
register_estimator_provider("phast_model.control", CONTROL_ESTIMATORS)
