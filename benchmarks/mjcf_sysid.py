"""``phast-mismatch`` side by side with MuJoCo's own ``mujoco.sysid`` on the same model files and recordings.

    python benchmarks/mjcf_sysid.py [--cases synthetic_arm dfki_c0] [--out DIR] [--data PATH] [--skip-ours CASE ...]
                                    [--weighting sysid|plain|wrapped] [--max-iters N]

For each case, on the same nominal MJCF file and the same recordings (same held-out trajectories):

* ours: ``analyze(file, recordings, holdout_trajectories=..., rollout_window=...)``;
* sysid: :func:`sysid_peer.fit_with_sysid` on the training trajectories only, with the parameters a
  MuJoCo user would pick, ``joints`` (every joint's armature, damping, frictionloss) and ``joints+masses`` (and every
  body mass); each fitted model file is written out and simulated by MuJoCo;
* one ``analyze(..., compare=...)`` call scores both sysid models (and the nominal file as MuJoCo simulates it,
  ``mujoco_nominal``) on the held-out recordings with the same windows, initial-state fits and metric as ours.

Printed (and with ``--out``: ``DIR/results.json``, ``DIR/results.md``, the fitted files ``DIR/<case>/*.xml``): the
held-out rollout RMSE of every model and its ratio to the nominal model's, wall times, and what each names (our
missing-physics rows with joint and MJCF attribute, our changed parameters; sysid's fitted values with 95% intervals).

``--skip-ours CASE``: our analysis of the real arm takes ~10 min; this scores the models through the same held-out
code (``HeldOut.evaluate``, as ``analyze`` builds it from the training recordings) without running the analysis.

Cases:

* ``synthetic_arm``: a 2-link arm (two hinges about y, two motors, RK4 at 2 ms); "reality" is the same file with
  frictionloss 0.02 on joint2 and armature 0.003 on joint1, recorded with MuJoCo from smooth random torques
  (12 trajectories x 400 samples, dt 0.01 s, q noise 0.002 rad); the last 3 are held out; 1-s rollout windows.
* ``dfki_c0``: the real DFKI C.0 arm, ``examples/robots/dfki_c0.xml`` (the published frictionless model) and
  ``dfki_double_pendulum_c0.npz`` (jittered time stamps ``t``); trajectories 2, 4, 6 held out; 1-s windows.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO))

DFKI_XML = REPO / "examples" / "robots" / "dfki_c0.xml"
DFKI_DATA = Path(os.environ.get("PHAST_REAL_DATA", REPO.parent / "shared" / "data" / "real")) / "dfki_double_pendulum_c0.npz"
PARAM_SETS = ("joints", "joints+masses")

ARM2_XML = """<mujoco model="arm2">
  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>
  <option gravity="0 0 -9.81" timestep="0.002" integrator="RK4">
    <flag contact="disable"/>
  </option>
  <default>
    <geom contype="0" conaffinity="0" type="capsule" size="0.02"/>
  </default>
  <worldbody>
    <body name="link1">
      <joint name="joint1" type="hinge" axis="0 1 0"/>
      <inertial pos="0 0 -0.15" mass="1.0" diaginertia="0.008 0.008 0.001"/>
      <geom fromto="0 0 0 0 0 -0.3"/>
      <body name="link2" pos="0 0 -0.3">
        <joint name="joint2" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 -0.125" mass="0.5" diaginertia="0.003 0.003 0.0005"/>
        <geom fromto="0 0 0 0 0 -0.25"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="motor1" joint="joint1"/>
    <motor name="motor2" joint="joint2"/>
  </actuator>
</mujoco>
"""
#: the synthetic arm's hidden reality: (joint, attribute) -> value
ARM2_HIDDEN = {("joint2", "frictionloss"): 0.02, ("joint1", "armature"): 0.003}
#: torque amplitude per motor (sum of three sines), N m
ARM2_TORQUE = (0.6, 0.1)  # swings up to ~1 rad (1.0 / 0.2 already whips link 2 round)


@dataclass
class Case:
    name: str
    xml: Path  # the nominal model file
    recordings: Any  # what analyze takes (a dict or an .npz path)
    arrays: dict[str, Any]  # q, u, dt or t: what fit_with_sysid takes
    holdout: list[int]
    rollout_window: float
    describe: str
    truth: dict[str, float] = field(default_factory=dict)  # "<element>.<attr>" -> the real value (synthetic only)
    real_xml: Path | None = None  # the synthetic reality's file
    extra: dict[str, Any] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------------ the cases


def _edit(xml: Path, edits: dict[tuple[str, str], float], out: Path) -> Path:
    """The model file with joint attributes set (element 0 of the array attributes of mujoco >= 4.0)."""
    import mujoco

    from phast_model.identify.mjcf_write import set_joint_attr

    spec = mujoco.MjSpec.from_file(str(xml))
    for (joint, attr), v in edits.items():
        set_joint_attr(spec.joint(joint), attr, v)
    out.write_text(spec.to_xml())
    return out


def _smooth_torques(rng: np.random.Generator, n_traj: int, n_steps: int, dt: float, amps: tuple[float, ...]) -> np.ndarray:
    """(n_traj, n_steps, m): per motor a sum of three sines, 0.2-1.2 Hz, random phases, total amplitude ``amps``."""
    t = np.arange(n_steps) * dt
    u = np.zeros((n_traj, n_steps, len(amps)))
    for b in range(n_traj):
        for j, a in enumerate(amps):
            w = rng.dirichlet(np.ones(3))
            f, ph = rng.uniform(0.2, 1.2, 3), rng.uniform(0, 2 * np.pi, 3)
            u[b, :, j] = a * np.sum(w[:, None] * np.sin(2 * np.pi * f[:, None] * t + ph[:, None]), axis=0)
    return u


def synthetic_case(work: Path, seed: int = 0, n_traj: int = 12, T: int = 400, dt: float = 0.01,
                   noise: float = 0.002) -> Case:
    from phast_model.identify.mujoco_sim import rollout_q

    work.mkdir(parents=True, exist_ok=True)
    nominal = work / "arm2_nominal.xml"
    nominal.write_text(ARM2_XML)
    real = _edit(nominal, ARM2_HIDDEN, work / "arm2_real.xml")
    rng = np.random.default_rng(seed)
    u = _smooth_torques(rng, n_traj, T - 1, dt, ARM2_TORQUE)
    q0, v0 = rng.uniform(-0.3, 0.3, (n_traj, 2)), np.zeros((n_traj, 2))
    q_true = rollout_q(str(real), q0, v0, u, dt, T - 1)
    q = q_true + noise * rng.standard_normal(q_true.shape)
    q_nom = rollout_q(str(nominal), q0, v0, u, dt, T - 1)
    w = int(round(1.0 / dt)) + 1
    eff = float(np.sqrt(np.mean((q_true[:, :w] - q_nom[:, :w]) ** 2)) / noise)
    rec = {"q": q, "u": u, "dt": dt}
    truth = {f"{j}.{a}": v for (j, a), v in ARM2_HIDDEN.items()}
    return Case("synthetic_arm", nominal, rec, rec, list(range(n_traj - 3, n_traj)), 1.0,
                "2-link arm; reality: frictionloss 0.02 on joint2, armature 0.003 on joint1", truth, real,
                {"effect_over_noise_first_1s": eff, "max_abs_q": np.abs(q_true).max(axis=(0, 1)).round(3).tolist(),
                 "n_traj": n_traj, "T": T, "dt": dt, "noise": noise})


def dfki_case(data: Path) -> Case:
    """The real arm; ``--data`` (default ``$PHAST_REAL_DATA/dfki_double_pendulum_c0.npz``)."""
    with np.load(data, allow_pickle=False) as z:
        arrays = {"q": z["q"], "u": z["u"], "t": z["t"]}
    return Case("dfki_c0", DFKI_XML, str(data), arrays, [2, 4, 6], 1.0,
                "real DFKI C.0 arm, published frictionless model; jittered time stamps", {}, None,
                {"n_traj": int(arrays["q"].shape[0]), "T": int(arrays["q"].shape[1]),
                 "median_dt": float(np.median(np.diff(arrays["t"], axis=1)))})


# ---------------------------------------------------------------------------------------------------- the runs


def run_sysid(case: Case, out: Path, max_iters: int, weighting: str = "sysid") -> dict[str, Any]:
    """Both sysid fits on the training trajectories; each fitted file written to ``out``."""
    from benchmarks.sysid_peer import fit_with_sysid

    n = int(np.shape(case.arrays["q"])[0])
    train = [k for k in range(n) if k not in case.holdout]
    results = {}
    for params in PARAM_SETS:
        print(f"[{case.name}] sysid {params} on trajectories {train} ...", file=sys.stderr, flush=True)
        res = fit_with_sysid(case.xml, case.arrays, train, params=params, window_s=case.rollout_window, max_iters=max_iters,
                             weighting=weighting)  # type: ignore[arg-type]
        res.write_xml(out / f"sysid_{params.replace('+', '_')}.xml")
        print(f"[{case.name}] sysid {params}: {res.wall_s:.1f} s, cost {res.cost_start:.4g} -> {res.cost_final:.4g}",
              file=sys.stderr, flush=True)
        results[params] = res
    return results


def _compare_models(case: Case, out: Path) -> dict[str, Any]:
    from phast_model.identify.mujoco_sim import mujoco_simulated

    models = {"mujoco_nominal": mujoco_simulated(case.xml)}
    if case.real_xml is not None:  # the synthetic reality itself: the floor set by the noise and initial-state fits
        models["mujoco_truth"] = mujoco_simulated(case.real_xml)
    for params in PARAM_SETS:
        models[f"sysid_{params}"] = mujoco_simulated(out / f"sysid_{params.replace('+', '_')}.xml")
    return models


def _ours(rep: Any) -> dict[str, Any]:
    rows = [{"term": r["term"], "joint": r.get("joint"), "mjcf": r.get("mjcf"), "coefficient": r["coefficient"],
             "ci95": r.get("ci95")} for r in rep.missing_physics]
    changed = {k: {"nominal": v.get("nominal"), "fitted": v.get("fitted"), "ci95": v.get("ci95")}
               for k, v in rep.sim["calibrated"].items() if v.get("ci95") is not None}
    return {"missing_physics": rows, "calibrated_changed": changed}


def score_with_analysis(case: Case, compare: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any], float]:
    """One ``analyze`` call: ours and the compared models on the held-out recordings -> (fit, ours, wall)."""
    from phast_model.mismatch import analyze

    t0 = time.time()
    rep = analyze(str(case.xml), case.recordings, holdout_trajectories=case.holdout, rollout_window=case.rollout_window,
                  compare=compare)
    wall = time.time() - t0
    fit = {k: {"rollout_rmse": v["rollout_rmse"]} for k, v in rep.fit.items() if isinstance(v, dict) and "rollout_rmse" in v}
    return fit, _ours(rep), wall


def score_only(case: Case, compare: dict[str, Any]) -> tuple[dict[str, Any], float]:
    """The held-out scores of the nominal model and ``compare`` as ``analyze`` computes them, without the analysis."""
    from phast_model.mismatch.analysis import held_out_scores

    t0 = time.time()
    metrics = held_out_scores(str(case.xml), case.recordings, compare, holdout_trajectories=sorted(case.holdout),
                              rollout_window=case.rollout_window)
    return {k: {"rollout_rmse": v["rollout_rmse"]} for k, v in metrics.items()}, time.time() - t0


def run_case(case: Case, out: Path, skip_ours: bool, max_iters: int, weighting: str = "sysid") -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    sysid = run_sysid(case, out, max_iters, weighting)
    compare = _compare_models(case, out)
    print(f"[{case.name}] scoring" + (" (our analysis skipped)" if skip_ours else " with our analysis") + " ...",
          file=sys.stderr, flush=True)
    if skip_ours:
        fit, score_s = score_only(case, compare)
        ours, ours_s = None, None
    else:
        fit, ours, ours_s = score_with_analysis(case, compare)
        score_s = ours_s
    nominal = fit["nominal"]["rollout_rmse"]
    ratios = {k: v["rollout_rmse"] / nominal for k, v in fit.items()}
    return {"case": case.name, "describe": case.describe, "model": str(case.xml.relative_to(REPO)) if case.xml.is_relative_to(REPO)
            else case.xml.name, "holdout_trajectories": case.holdout, "rollout_window_s": case.rollout_window,
            "truth": case.truth, **case.extra, "fit": fit, "ratio_over_nominal": ratios, "ours": ours, "ours_wall_s": ours_s,
            "score_wall_s": score_s,
            "sysid": {p: r.as_dict() for p, r in sysid.items()}}


# -------------------------------------------------------------------------------------------------- the tables


def _fmt_ci(v: dict[str, Any]) -> str:
    ci = v["ci95"]
    return "" if ci is None else (" +- inf" if not np.isfinite(ci) else f" +- {ci:.2g}")


def sysid_named(r: dict[str, Any], params: str, tol: float = 1e-3) -> str:
    """sysid's fitted values that moved off zero / their file value (all joints' attributes are fitted)."""
    vals = r["sysid"][params]["values"]
    out = []
    for k, v in vals.items():
        moved = abs(v["fitted"] - v["start"]) > tol * max(abs(v["start"]), v["upper"] * 1e-2)
        if moved:
            out.append(f"{k}={v['fitted']:.4g}{_fmt_ci(v)}" + (" (at bound)" if v["at_bound"] else ""))
    return ", ".join(out) or "-"


def ours_named(r: dict[str, Any]) -> str:
    if r["ours"] is None:
        return "(not run)"
    rows = [f"{m['term']}[{m['joint']}] -> {m['mjcf']} {m['coefficient']:.4g}" for m in r["ours"]["missing_physics"]]
    n = len(r["ours"]["calibrated_changed"])
    return ", ".join(rows) + (f"; {n} parameter(s) recalibrated" if n else "") or "-"


COLUMNS = (("ours augmented", "augmented"), ("ours calibrated_xml", "calibrated_xml"), ("sysid joints", "sysid_joints"),
           ("sysid joints+masses", "sysid_joints+masses"), ("MuJoCo nominal", "mujoco_nominal"),
           ("MuJoCo truth", "mujoco_truth"))


def markdown(rows: list[dict[str, Any]]) -> str:
    lines = ["Held-out rollout RMSE over the nominal model's (rad; lower is better; same windows and metric for all)", "",
             "| case | nominal RMSE | " + " | ".join(c for c, _ in COLUMNS) + " | ours wall s | sysid wall s (joints / +masses) |",
             "|---" * (len(COLUMNS) + 4) + "|"]
    for r in rows:
        cells = [f"{r['ratio_over_nominal'][k]:.3f}" if k in r["ratio_over_nominal"] else "-" for _, k in COLUMNS]
        ow = "-" if r["ours_wall_s"] is None else f"{r['ours_wall_s']:.0f}"
        sw = " / ".join(f"{r['sysid'][p]['wall_s']:.0f}" for p in PARAM_SETS)
        lines.append(f"| {r['case']} | {r['fit']['nominal']['rollout_rmse']:.4g} | " + " | ".join(cells) + f" | {ow} | {sw} |")
    lines += ["", "What each names:", ""]
    for r in rows:
        lines.append(f"* **{r['case']}** ({r['describe']})" + (f"; truth: {r['truth']}" if r["truth"] else ""))
        lines.append(f"  * ours: {ours_named(r)}")
        for p in PARAM_SETS:
            lines.append(f"  * sysid {p}: {sysid_named(r, p)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", default=["synthetic_arm", "dfki_c0"])
    ap.add_argument("--out", default=None, help="write DIR/results.json, DIR/results.md and DIR/<case>/sysid_*.xml")
    ap.add_argument("--data", default=str(DFKI_DATA), help="the real arm's dfki_double_pendulum_c0.npz")
    ap.add_argument("--skip-ours", nargs="*", default=[], help="cases scored without our analysis (see above)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-iters", type=int, default=50, help="sysid optimizer iterations")
    ap.add_argument("--weighting", choices=("sysid", "plain", "wrapped"), default="sysid",
                    help="sysid's residual: its default (per-window normalised) or plain q errors (sysid_peer.plain_residual)")
    args = ap.parse_args(argv)
    bad = sorted(set(args.cases) - {"synthetic_arm", "dfki_c0"})
    if bad:
        print(f"mjcf_sysid: unknown case(s) {bad}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path(os.environ.get("TMPDIR", "/tmp")) / "mjcf_sysid"
    rows = []
    for name in args.cases:
        case = synthetic_case(out / name, args.seed) if name == "synthetic_arm" else dfki_case(Path(args.data))
        rows.append(run_case(case, out / name, name in args.skip_ours, args.max_iters, args.weighting))
        if args.out:  # after every case, so a long run keeps what it has
            (out / "results.json").write_text(json.dumps({"command": " ".join(sys.argv), "rows": rows}, indent=1,
                                                         default=float))
            (out / "results.md").write_text(markdown(rows) + "\n")
    print(markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
