"""The "parameters before terms" cases of docs/mismatch_claims.md that are larger than a bench case.

    python benchmarks/mismatch_trust_cases.py --cases arm_motor two_laws short_real three_link --json out.json

* ``arm_motor``: a two-motor arm (the DFKI C.0 CAD values, joint coordinates, 40 x 600 samples at 100 Hz, smooth
  random torques on both motors, q-noise 0.002 rad) with armature 0.004 kg m^2 and Coulomb friction 0.10 / 0.08 N m
  at the two joints;
* ``two_laws``: a pendulum with viscous 0.003 + quadratic drag 0.001 (40 x 400, q-noise 0.002);
* ``short_real``: segment 6 of the real pendulum cut into six 1-s windows at 200 Hz (needs the real recordings,
  ``$PHAST_REAL_DATA`` or ``../shared/data/real``);
* ``three_link``: the three-link pendulum user rig (``examples/rigs/triple_pendulum.py``), 26 free-swing pieces x
  1500 samples at 1 kHz, all nine link parameters 3-8% off, Coulomb friction 3, 2, 1 mN m at the joints, the last
  9 pieces held out (the time target is 3 min on one core).

Each prints what the tool reports (parameter changes, terms, held-out rollout RMSE) and its wall time.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("PHAST_REAL_DATA", REPO.parent / "shared" / "data" / "real"))
ARM = {"coordinates": "relative", "mass1": 0.6417, "mass2": 0.5639, "length1": 0.2, "length2": 0.3,
       "com1": 0.2, "com2": 0.3213, "inertia1": 0.02671, "inertia2": 0.05388, "gravity": 9.81}
RIG = f"{REPO / 'examples' / 'rigs' / 'triple_pendulum.py'}:TriplePendulum"


def _case(name: str, seed: int) -> tuple[str, dict[str, Any], dict[str, Any], dict[str, Any]]:
    """(sim, sim_kwargs, recordings, analyze options) of one case."""
    from phast_model.bench.reality import make_reality
    from phast_model.identify.simulators import load_simulator
    from phast_model.mismatch import Term

    if name == "arm_motor":
        terms = [Term("armature", 0, 0.004), Term("armature", 1, 0.004), Term("coulomb_friction", 0, 0.1),
                 Term("coulomb_friction", 1, 0.08)]
        rec = make_reality("PHAST/DoublePendulum-v0", terms, ARM, 40, 600, 0.002, seed, u_std=0.5)
        return "PHAST/DoublePendulum-v0", ARM, rec, {"rollout_window": 1.0}
    if name == "two_laws":
        terms = [Term("viscous_damping", 0, 0.003), Term("quadratic_drag", 0, 0.001)]
        return "PHAST/Pendulum-v0", {}, make_reality("PHAST/Pendulum-v0", terms, {}, 40, 400, 0.002, seed), {}
    if name == "short_real":
        with np.load(DATA / "multiarm_single_pendulum.npz") as z:
            q = np.stack([z["q"][5, i * 1000:(i + 1) * 1000:5] - math.pi for i in range(6)])
            fit = dict(zip([str(s) for s in z["published_fit_names"]], [float(v) for v in z["published_fit"]]))
        kw = {"mass": fit["m1_kg"], "length": fit["a1_m"], "gravity": fit["g"],
              "inertia": fit["m1_kg"] * fit["a1_m"] ** 2 + fit["I1_kgm2"], "gamma": fit["k1_viscous"]}
        return "PHAST/DampedPendulum-v0", kw, {"q": q, "dt": 0.005, "angle_dims": np.array([0])}, {}
    if name == "three_link":
        nom = load_simulator(RIG).build().params
        rng = np.random.default_rng(seed)
        true = {k: nom[k] * (1 + rng.choice([-1, 1]) * rng.uniform(0.03, 0.08))
                for k in ("mass1", "mass2", "mass3", "com1", "com2", "com3", "inertia1", "inertia2", "inertia3")}
        terms = [Term("coulomb_friction", 0, 3e-3), Term("coulomb_friction", 1, 2e-3), Term("coulomb_friction", 2, 1e-3)]
        rec = make_reality(RIG, terms, true, n_traj=26, T=1500, noise_std=2e-4, seed=1)
        return RIG, {}, rec, {"holdout_trajectories": list(range(17, 26))}
    raise ValueError(f"unknown case {name!r}")


CASES = ("arm_motor", "two_laws", "short_real", "three_link")
SEEDS = {"arm_motor": 11, "two_laws": 11, "short_real": 0, "three_link": 0}


def run(name: str, progress: bool = False) -> dict[str, Any]:
    from phast_model.mismatch import analyze

    sim, kw, rec, opts = _case(name, SEEDS[name])
    t0 = time.time()
    rep = analyze(sim, rec, sim_kwargs=kw, progress=progress, **opts)
    return {"case": name, "wall_s": round(time.time() - t0, 1),
            "changed": {k: v["relative_change"] for k, v in rep.sim["calibrated"].items() if v.get("ci95")},
            "terms": [(m["term"], m["coordinate"], m["coefficient"]) for m in rep.missing_physics],
            "heldout_rollout_rmse": {k: v["rollout_rmse"] for k, v in rep.fit.items() if isinstance(v, dict) and "rollout_rmse" in v},
            "summary": rep.summary}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", default=list(CASES), choices=CASES)
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    ap.add_argument("--progress", action="store_true", help="the tool's progress lines")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    from phast_gym.fileio import atomic_write_json

    rows = []
    for name in tqdm(args.cases, desc="trust cases", file=sys.stderr):
        row = run(name, args.progress)
        rows.append(row)
        print(f"{name}: {row['wall_s']} s; changed {row['changed']}; terms {row['terms']}; "
              f"held-out {row['heldout_rollout_rmse']}", flush=True)
    if args.json:
        atomic_write_json(args.json, rows, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
