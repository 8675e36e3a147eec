"""The PHAST world model: configuration, the Strang-split core, the model and its regimes, rollouts, and the
Gymnasium env that steps a trained model (``gym_env.PHASTWorldModelEnv``).  Components (potential, mass,
damping, friction, observer) live in :mod:`phast_model.components`."""
