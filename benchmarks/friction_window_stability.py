"""How much does the real pendulum's friction-law choice depend on the weak-form filter window?

Runs the mismatch tool once (for its calibrated model and held-out settings), then the law selector alone
(:func:`phast_model.mismatch.friction.select_law`, segments 1-4) at several filter windows and sampling rates,
and scores each chosen law on the held-out segments 5-6 with the tool's own evaluation (ratio published /
augmented rollout RMSE, as the report's headline).

    python benchmarks/friction_window_stability.py [--data PATH] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from phast_gym.fileio import atomic_write_json

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))

#: (decimation of the 1 kHz recording, filter window in samples at that rate)
SETTINGS = ((6, 9), (6, 17), (6, 23), (6, 33), (3, 45), (1, 51), (1, 101))


def main(argv: list[str] | None = None) -> int:
    from real_pendulum_mismatch import DEFAULT_DATA, load

    from phast_model.identify.recordings import validate
    from phast_model.identify.shooting import smooth
    from phast_model.mismatch import analyze
    from phast_model.mismatch.evaluate import evaluate_models
    from phast_model.mismatch.friction import select_law

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    raw, kwargs = load(args.data)
    report = analyze("PHAST/Pendulum-v0", raw, sim_kwargs=kwargs, holdout_fraction=2 / 6)
    calibrated = report.plot_data["calibrated_system"]
    published = report.fit["nominal"]["rollout_rmse"]
    held = report.plot_data["hold"]
    sigma = np.asarray(report.data["noise_std_per_coordinate"])
    smoothing_window = int(report.details["smoothing_window_samples"])
    qs, vs = smooth(held.q, held.dt, smoothing_window)
    x_scale = np.array([np.sqrt(np.mean(qs**2)), np.sqrt(np.mean(vs**2))])
    K = int(report.fit["rollout_init_samples"])
    rec = validate(raw, 1, (0,), "real pendulum")
    rows = []
    for dec, window in SETTINGS:
        train = rec.decimate(dec).subset(slice(0, 4))
        sel = select_law(calibrated, train, window=window)
        res, _ = evaluate_models({"a": sel.chosen.augmented(calibrated)}, held, sigma, x_scale, K, smoothing_window, np.ones(1))
        row = {"decimation": dec, "window_samples": window, "window_s": round(window * 0.001 * dec, 4), "law": sel.chosen_name,
               "ratio_published_over_augmented": published / res["a"]["rollout_rmse"]}
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.json:
        atomic_write_json(args.json, {"command": "python benchmarks/friction_window_stability.py", "rows": rows}, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
