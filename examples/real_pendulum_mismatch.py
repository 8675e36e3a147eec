"""The mismatch tool on a real pendulum: what did the published viscous model leave out?

Data: ``multiarm_single_pendulum.npz`` (Kaheman et al. 2022, arXiv:2205.06231, MIT License;
free swing of one arm, encoder at 1 kHz, 6 consecutive segments).  It is not shipped with the
package: ``--data PATH``, or ``$PHAST_REAL_DATA`` naming its directory (default: the project
workspace's ``../shared/data/real/`` next to the repository); a missing file is a clear error.  The nominal
simulator is PHAST/Pendulum-v0 with the authors' published fit (viscous
friction only).  The recording puts theta = pi hanging, so ``angle_offset = pi``
maps it to the env's convention (0 hanging, same direction); the real arm is
not a point mass, so its inertia about the pivot is I = m a^2 + I1 (the
``inertia`` kwarg).  Segments 1-4 are fitted, 5-6 held out.

    python examples/real_pendulum_mismatch.py --out real_pendulum_report [--json headline.json]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.fileio import atomic_write_json

REPO = Path(__file__).resolve().parents[1]
#: directory of the real recordings: $PHAST_REAL_DATA, else the project workspace's data next to the repository
DATA_DIR = Path(os.environ.get("PHAST_REAL_DATA", REPO.parent / "shared" / "data" / "real"))
DEFAULT_DATA = DATA_DIR / "multiarm_single_pendulum.npz"


def load(path: Path, n_seg: int = 6, max_T: int | None = None) -> tuple[dict[str, Any], dict[str, float]]:
    """Recordings dict (docs/mismatch.md keys) and the published-model env kwargs."""
    if not path.exists():
        raise ValueError(f"real-pendulum data not found at {path}; pass --data or set PHAST_REAL_DATA to its directory")
    with np.load(path) as z:
        q, dt = z["q"][:n_seg], float(z["dt"])
        fit = dict(zip([str(s) for s in z["published_fit_names"]], [float(v) for v in z["published_fit"]]))
    if max_T:
        q = q[:, :max_T]
    a1, m1, I1 = fit["a1_m"], fit["m1_kg"], fit["I1_kgm2"]
    kwargs = {"mass": m1, "length": a1, "gravity": fit["g"], "inertia": m1 * a1**2 + I1, "gamma": fit["k1_viscous"]}
    rec = {"q": q, "dt": dt, "angle_dims": np.array([0]), "angle_offset": math.pi}
    return rec, kwargs


def run(data: Path = DEFAULT_DATA, out: Path | None = None, max_T: int | None = None, progress: bool = True,
        shoot_window: int | None = None, rollout_window: float | None = None) -> dict[str, Any]:
    """Analyze the recording; returns headline numbers (and writes the report to ``out``)."""
    from phast_model.mismatch import analyze

    rec, kwargs = load(Path(data), max_T=max_T)
    # 6 segments, hold out the last 2 (segments 5-6): holdout_fraction 2/6
    report = analyze("PHAST/Pendulum-v0", rec, sim_kwargs=kwargs, holdout_fraction=2 / 6, progress=progress,
                     shoot_window=shoot_window, rollout_window=rollout_window)
    if out is not None:
        report.write(out)
    f = report.fit
    fr = report.details.get("friction", {})
    curve = [{"speed_band": b["band"], "friction_nm": b["curve"], "ci95": b["ci95"], "chosen_law_nm": b["law"], "inside": b["inside"]}
             for b in fr.get("law_vs_curve", []) if b["direction"] == "both"]
    res = {
        "missing_physics": [{k: m[k] for k in ("term", "coordinate", "coefficient", "ci95")} for m in report.missing_physics],
        "calibrated": {k: {"fitted": v["fitted"], "ci95": v["ci95"]} for k, v in report.sim["calibrated"].items() if v.get("ci95")},
        "heldout_rollout_rmse_rad": {k: f[k]["rollout_rmse"] for k in ("nominal", "calibrated", "augmented")},
        "rollout_window_s": f.get("rollout_window_s"),
        "improvement_vs_published": f["nominal"]["rollout_rmse"] / max(f["augmented"]["rollout_rmse"], 1e-300),
        "every_ci_excludes_zero": all(m["ci95"][0] * m["ci95"][1] > 0 for m in report.missing_physics),
        "friction_law": fr.get("law", {}).get("law"),
        "total_friction_passive": fr.get("passivity", {}).get("passive"),
        "friction_curve_training": curve,
        "noise_std_rad": report.data["noise_std"],
        "wall_time_s": report.details.get("wall_time_s"),
        "summary": report.summary,
    }
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="path to multiarm_single_pendulum.npz")
    ap.add_argument("--out", type=Path, default=Path("real_pendulum_report"), help="report directory")
    ap.add_argument("--max-T", type=int, default=None, help="use only the first samples of each segment (faster)")
    ap.add_argument("--shoot-window", type=int, default=None, help="shooting window in (decimated) samples")
    ap.add_argument("--rollout-window", type=float, default=None,
                    help="held-out open-loop window [s] (default: each held-out segment whole, 9.2 s)")
    ap.add_argument("--json", type=Path, default=None, help="also write the printed headline numbers to this JSON file")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    args = ap.parse_args(argv)
    try:
        res = run(args.data, args.out, args.max_T, progress=not args.quiet, shoot_window=args.shoot_window,
                  rollout_window=args.rollout_window)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json is not None:
        atomic_write_json(args.json, res, indent=1)
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
