"""The learned cart-pole's mass matrix and potential curvature at the upright and at hanging (issue 55's checks).

    python inspect_model.py MODEL_DIR [MODEL_DIR ...]
"""
import sys

import numpy as np

from phast_gym.control.controller import potential_curvature
from phast_model.api import load_run
from phast_model.rl.hold import learned_system

for d in sys.argv[1:]:
    m = load_run(d)
    s = learned_system(m, 0.01)
    up = np.array([0.0, np.pi])
    print(d, "M(pi)", np.round(np.array(s.mass_matrix(list(up))), 4).tolist(), "Hess V(pi)",
          np.round(potential_curvature(s, up), 4).tolist())
    print("  friction", None if m.friction is None else m.friction.coefficients())
