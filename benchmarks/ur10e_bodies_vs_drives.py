"""Where the UR10e answer and the authors' identified model differ: the bodies or the drives.

Crosses two sets of link parameters (the URDF's, the authors' ``pi_rgd``) with three sets of drives (none, the
answer of ``phast-mismatch``, the authors' ``pi_drvs`` + Fv + Fc) and scores the six models on the held-out runs with
``phast-mismatch``'s own held-out code (``held_out_scores``; MuJoCo simulates every model).

    python examples/real_ur10e_mismatch.py --data ~/dynamic_calibration --out ur10e/      # the answer first
    python benchmarks/ur10e_bodies_vs_drives.py --data ~/dynamic_calibration --run ur10e/ --out hybrids.json
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
TERMS = {"armature": "armature", "viscous_damping": "damping", "coulomb_friction": "frictionloss"}


def _example() -> ModuleType:
    """examples/real_ur10e_mismatch.py as a module (its reader of the authors' parameters)."""
    spec = importlib.util.spec_from_file_location("real_ur10e_mismatch", REPO / "examples" / "real_ur10e_mismatch.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _drives(ex: ModuleType, vec: dict[str, np.ndarray], report: dict[str, Any]) -> dict[str, list[dict[str, float]]]:
    """Per drive set, per joint: {MuJoCo attribute: value}."""
    ours: list[dict[str, float]] = [{} for _ in range(6)]
    for row in report["missing_physics"]:
        if row["term"] in TERMS:
            ours[row["coordinate"]][TERMS[row["term"]]] = float(row["coefficient"])
    return {"none": [{} for _ in range(6)], "ours": ours, "authors": ex.authors_drives(vec)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, help="checkout of shamilmamedov/dynamic_calibration")
    p.add_argument("--run", required=True, help="the example's --out folder (recordings.npz, runs.json, report/)")
    p.add_argument("--out", required=True, help="JSON of the six held-out scores")
    args = p.parse_args(argv)
    from phast_model.cli.mismatch import checked_recordings
    from phast_model.identify.mujoco_sim import mujoco_simulated
    from phast_model.mismatch.analysis import held_out_scores

    ex, data, run = _example(), Path(args.data), Path(args.run)
    report = json.loads((run / "report" / "report.json").read_text())
    facts = json.loads((run / "runs.json").read_text())
    held = list(range(len(facts["train"]), len(facts["train"]) + len(facts["held_out"])))
    urdf = str(data / ex.URDF)
    vec = ex.authors_parameters(data)
    bodies = {"urdf": None, "authors": vec["pi_rgd"]}
    with tempfile.TemporaryDirectory() as d:
        models = {f"{b}_bodies+{name}_drives": mujoco_simulated(ex.urdf_model(data, drives, Path(d) / f"{b}_{name}.xml",
                                                                               links))
                  for b, links in bodies.items() for name, drives in _drives(ex, vec, report).items()}
        rec = checked_recordings(urdf, str(run / "recordings.npz"), {})
        assert not isinstance(rec, str), "a model file's recordings come back validated"
        window = (report["fit"]["rollout_window_samples"] - 1) * rec.dt  # the report's windows, sample for sample
        scores = held_out_scores(urdf, rec, models, holdout_trajectories=held, rollout_window=window)
    out = {k: {"rollout_rmse": v["rollout_rmse"], "one_step_mse": v["one_step_mse"]} for k, v in scores.items()}
    for k, v in out.items():
        print(f"{k:32s} {v['rollout_rmse']:.4f} ({v['rollout_rmse'] / out['nominal']['rollout_rmse']:.3f}x)")
    Path(args.out).write_text(json.dumps({"held_out": held, "scores": out}, indent=1))
    return 0 if np.isfinite(out["nominal"]["rollout_rmse"]) else 1


if __name__ == "__main__":
    sys.exit(main())
