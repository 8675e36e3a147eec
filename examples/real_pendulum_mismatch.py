"""The mismatch tool on a real pendulum: what did the published viscous model leave out?

Data: ../shared/data/real/multiarm_single_pendulum.npz (Kaheman et al. 2022,
free swing of one arm, encoder at 1 kHz, 6 consecutive segments).  The nominal
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

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "real" / "multiarm_single_pendulum.npz"


def load(path: Path, n_seg: int = 6, max_T: int | None = None) -> tuple[dict[str, Any], dict[str, float]]:
    """Recordings dict (MISMATCH.md keys) and the published-model env kwargs."""
    if not path.exists():
        raise ValueError(f"real-pendulum data not found at {path}; pass --data")
    with np.load(path) as z:
        q, dt = z["q"][:n_seg], float(z["dt"])
        fit = dict(zip([str(s) for s in z["published_fit_names"]], [float(v) for v in z["published_fit"]]))
    if max_T:
        q = q[:, :max_T]
    a1, m1, I1 = fit["a1_m"], fit["m1_kg"], fit["I1_kgm2"]
    kwargs = {"mass": m1, "length": a1, "gravity": fit["g"], "inertia": m1 * a1**2 + I1, "gamma": fit["k1_viscous"]}
    rec = {"q": q, "dt": dt, "angle_dims": np.array([0]), "angle_offset": math.pi}
    return rec, kwargs


def decrements(path: Path) -> list[tuple[float, float]]:
    """(amplitude, decrement to the next peak) of every swing of the whole recording (peaks of q - pi)."""
    from scipy.signal import find_peaks

    with np.load(path) as z:
        q = z["q"][..., 0] - math.pi
    peaks = np.concatenate([seg[find_peaks(seg, distance=300)[0]] for seg in q])
    return [(float(a), float(a - b)) for a, b in zip(peaks[:-1], peaks[1:])]


#: velocity-power friction laws F = c |qdot|^n sign(qdot) compared by :func:`decay_laws`
DECAY_LAWS = {"coulomb": 0, "viscous": 1, "quadratic_drag": 2, "cubic_drag": 3}


def decay_laws(path: Path, n_fit: int = 4) -> dict[str, Any]:
    """Can segments 1..n_fit tell which friction law holds at the held-out amplitudes?  Model-free check on the
    swing peaks: the energy lost per full swing (E = 1 - cos A in units of m g a, consecutive positive peaks A)
    is regressed (non-negative least squares) on each combination of velocity-power laws, whose loss over a
    swing of amplitude A is proportional to the integral of (cos th - cos A)^(n/2) over th in [-A, A] (the
    energy-conserving velocity profile).  For each combination: fit residual and BIC on segments 1..n_fit, and
    the measured / predicted loss on each later segment."""
    from itertools import combinations

    from scipy.integrate import quad
    from scipy.optimize import nnls
    from scipy.signal import find_peaks

    with np.load(path) as z:
        q = z["q"][..., 0] - math.pi
    amp, seg = [], []
    for s, x in enumerate(q):
        for j in find_peaks(x, distance=300)[0]:
            if 0 < j < len(x) - 1:  # parabolic refinement of the sampled peak
                y0, y1, y2 = x[j - 1], x[j], x[j + 1]
                den = y0 - 2 * y1 + y2
                amp.append(y1 - 0.125 * (y0 - y2) ** 2 / den if den != 0 else y1)
                seg.append(s)
    amp_a, seg_a = np.array(amp), np.array(seg)
    same = seg_a[:-1] == seg_a[1:]
    a0, a1, sg = amp_a[:-1][same], amp_a[1:][same], seg_a[1:][same]
    loss = np.cos(a1) - np.cos(a0)
    am = 0.5 * (a0 + a1)

    def swing_integral(a: float, n: int) -> float:
        return 2.0 * quad(lambda th: max(math.cos(th) - math.cos(a), 0.0) ** (n / 2), -a, a, limit=200)[0]

    basis = np.array([[swing_integral(a, n) for n in DECAY_LAWS.values()] for a in am])
    fit = sg < n_fit
    names = list(DECAY_LAWS)
    rows = []
    for k in (1, 2, 3):
        for combo in combinations(range(len(names)), k):
            X = basis[:, combo]
            scale = X[fit].std(0) + 1e-300
            c, _ = nnls(X[fit] / scale, loss[fit])
            pred = (X / scale) @ c
            rss = float(np.sum((loss - pred)[fit] ** 2))
            m = int(fit.sum())
            rows.append({"laws": [names[i] for i in combo], "fit_rms": math.sqrt(rss / m),
                         "bic": m * math.log(rss / m) + len(combo) * math.log(m),
                         "measured_over_predicted": {f"segment {s + 1}": float(loss[sg == s].sum() / pred[sg == s].sum())
                                                     for s in range(n_fit, int(sg.max()) + 1)}})
    rows.sort(key=lambda r: r["bic"])
    best = rows[0]["bic"]
    tied = [r for r in rows if r["bic"] - best < 2.0]  # not distinguishable on the fitted segments
    spread = {key: [min(r["measured_over_predicted"][key] for r in tied), max(r["measured_over_predicted"][key] for r in tied)]
              for key in rows[0]["measured_over_predicted"]}
    return {"n_swings_fitted": int(fit.sum()), "n_swings_held_out": int((~fit).sum()), "combinations": rows,
            "indistinguishable_on_fitted_segments": [r["laws"] for r in tied],
            "their_held_out_measured_over_predicted_range": spread}


def per_segment(report: Any) -> list[dict[str, Any]]:
    """Is the friction law the same in all six segments?  Per segment, the energy balance with every found dissipative
    term but Coulomb friction held at its training value, and one Coulomb coefficient fitted on that segment alone
    (an effective constant friction torque, comparable across amplitudes)."""
    from phast_model.mismatch.energy import DISSIPATIVE, energy_balance

    found = [m for m in report.missing_physics if m["term"] in DISSIPATIVE]
    if not any(m["term"] == "coulomb_friction" for m in found):
        return []
    held = tuple((m["term"], m["coordinate"], m["coefficient"], *([m["stribeck_velocity"]] if "stribeck_velocity" in m else []))
                 for m in found if m["term"] != "coulomb_friction")
    aug = report.augmented_system()
    train, hold = report.plot_data["train"], report.plot_data["hold"]
    sg = int(report.details["smoothing_window_samples"])
    out = []
    for j, (r, k) in enumerate([(train, k) for k in range(train.n_traj)] + [(hold, k) for k in range(hold.n_traj)]):
        eb = energy_balance(aug.base, r.subset(slice(k, k + 1)), sg, aug.coulomb_eps, candidates=("coulomb_friction",),
                            min_intervals=4, select=False, fixed=held)
        if eb is None:
            continue
        q = r.q[k, :, 0]
        t = eb.terms[0]
        out.append({"segment": j + 1, "held_out": r is hold,
                    "amplitude_range_rad": [float(np.abs(q[-200:]).max()), float(np.abs(q[:200]).max())],
                    "held_at_training_value": [h[0] for h in held],
                    "effective_coulomb": {"coefficient": t["coefficient"], "ci95": t["ci95"]}})
    return out


def heldout_law_diagnostic(report: Any) -> float | None:
    """DIAGNOSTIC ONLY (uses the held-out segments, so it is not a result): the held-out rollout RMSE of the augmented
    model when its dissipative coefficients are refitted by the energy balance on the held-out segments themselves.
    It bounds what any stationary law of the same form fitted on segments 1-4 could reach."""
    from phast_model.mismatch.energy import DISSIPATIVE, energy_balance
    from phast_model.mismatch.evaluate import evaluate_models
    from phast_model.mismatch.shooting import smooth
    from phast_model.mismatch.terms import AugmentedSystem, Term

    names = tuple(m["term"] for m in report.missing_physics if m["term"] in DISSIPATIVE)
    aug, hold = report.augmented_system(), report.plot_data["hold"]
    sg = int(report.details["smoothing_window_samples"])
    eb = energy_balance(aug.base, hold, sg, aug.coulomb_eps, candidates=names, min_intervals=4, select=False)
    if not names or eb is None:
        return None
    law = {t["term"]: max(t["coefficient"], 0.0) for t in eb.terms}
    terms = [Term(t.name, t.coordinate, law.get(t.name, t.coefficient)) for t in aug.terms]
    model = AugmentedSystem(aug.base, terms, aug.coulomb_eps)
    qs, vs = smooth(hold.q, hold.dt, sg)
    x_scale = np.array([float(np.sqrt(np.mean(qs**2))), float(np.sqrt(np.mean(vs**2)))])
    sigma = np.array(report.data["noise_std_per_coordinate"])
    res, _ = evaluate_models({"m": model}, hold, sigma, x_scale, int(report.fit["rollout_init_samples"]), sg, np.ones(1))
    return res["m"]["rollout_rmse"]


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
    res = {
        "missing_physics": [{k: m[k] for k in ("term", "coordinate", "coefficient", "ci95")} for m in report.missing_physics],
        "calibrated": {k: {"fitted": v["fitted"], "ci95": v["ci95"]} for k, v in report.sim["calibrated"].items() if v.get("ci95")},
        "heldout_rollout_rmse_rad": {k: f[k]["rollout_rmse"] for k in ("nominal", "calibrated", "augmented")},
        "rollout_window_s": f.get("rollout_window_s"),
        "energy_balance_used": report.details.get("energy_balance", {}).get("used", False),
        "per_segment_energy_balance": per_segment(report),
        "diagnostic_heldout_rmse_with_law_fitted_on_heldout": heldout_law_diagnostic(report),
        "decay_law_identifiability": decay_laws(Path(data)),
        "improvement_vs_published": f["nominal"]["rollout_rmse"] / max(f["augmented"]["rollout_rmse"], 1e-300),
        "every_ci_excludes_zero": all(m["ci95"][0] * m["ci95"][1] > 0 for m in report.missing_physics),
        "noise_std_rad": report.data["noise_std"],
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
    ap.add_argument("--decrements", action="store_true", help="only print the swing-peak decrements of the recording")
    ap.add_argument("--decay-laws", action="store_true",
                    help="only run the swing-peak check of which friction laws segments 1-4 can tell apart (JSON)")
    args = ap.parse_args(argv)
    try:
        if args.decrements:
            for a, d in decrements(args.data)[::6]:
                print(f"amplitude {a:.4f} rad  decrement {d:.5f} rad  ratio {d / a:.4f}")
            return 0
        if args.decay_laws:
            print(json.dumps(decay_laws(args.data), indent=1))
            return 0
        res = run(args.data, args.out, args.max_T, shoot_window=args.shoot_window, rollout_window=args.rollout_window)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    text = json.dumps(res, indent=1)
    if args.json is not None:
        tmp = args.json.with_name(args.json.name + ".tmp")
        tmp.write_text(text + "\n")
        os.replace(tmp, args.json)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
