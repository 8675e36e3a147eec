"""The mismatch tool on a real UR10e: the published URDF against the published logs, read as they come (issue 51).

Data: the GitHub repository shamilmamedov/dynamic_calibration (Innopolis University; not shipped here, no licence to
copy it): ``--data DIR`` names a checkout, or ``$PHAST_UR10E_DATA``.  Read as published:

* ``dataset_ur10e/identification_data/*.csv`` (and ``validation_data/``): no header, one row per sample:
  t, q1..q6 [rad], qd1..qd6, i1..i6 (measured motor current [A]) [, i_des1..6, tau_des1..6]
  (the repository's ``utils/data_processing/parseURData.m``; the 2019 files have 19 columns).  The runs have their own
  lengths, and a few rows are truncated or a logger's garbage: the recordings loader cuts the runs into equal pieces
  and drops and counts those rows (:mod:`phast_model.identify.logs`).
* ``URe/urdf/ur10e.urdf`` as published, its meshes absent (the loader drops visual and mesh geometry: the inertias
  come from ``<inertial>``; one torque motor per joint).

The input is u = drive gain x measured current, a joint torque [N m]: by default the authors' gains ``drvGains`` of
``UR10E_parameters.txt``; ``--drive-gains '[...]'`` (six gains) or ``--current-scale`` (one factor on all of them)
are the user's model choice.  Runs with a payload (file names with ``load`` but not ``unload``, as the repository's
``estimate_drive_gains.m`` uses them) are left out: the URDF carries no payload.  Held out: runs the fit never saw
(default: the validation run ``ur-20_01_17-ptp_10_points`` and the identification run ``ur-20_02_19_15harm50sec``).

    python examples/real_ur10e_mismatch.py --data ~/dynamic_calibration --out ur10e/ [--quick] [--convert-only]

Writes ``OUT/recordings.npz`` (the runs in the log-set format of docs/mismatch.md: q_k, t_k, u_k), ``OUT/runs.json``
(what was read, dropped and held out) and, unless ``--convert-only``, the ``phast-mismatch`` report in ``OUT/report/``;
with ``--world-model`` also a PHAST world model of the arm (``phast-train`` PARTIAL on the URDF) in ``OUT/world_model/``,
``calibrated.xml`` and the authors' model scored on its held-out windows.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

#: the authors' drive gains (UR10E_parameters.txt, drvGains): joint torque [N m] per motor current [A]
DRIVE_GAINS = (10.0000, 10.6956, 8.4566, 9.0029, 9.4800, 10.1232)
#: the URDF's joints, in the logs' column order (base, shoulder, elbow, wrist 1..3)
JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
#: columns of a log row (parseURData.m): time, positions, measured currents
T_COL, Q_COLS, I_COLS = 0, slice(1, 7), slice(13, 19)
#: runs held out by default (file name stems)
HOLDOUT = ("ur-20_01_17-ptp_10_points", "ur-20_02_19_15harm50sec")
#: --quick: training runs, seconds per run, held-out runs
QUICK = {"max_runs": 3, "max_seconds": 8.0, "holdout": HOLDOUT[:1]}
#: where the dataset lives in the repository
DATASET, URDF = Path("dataset_ur10e"), Path("URe/urdf/ur10e.urdf")
FETCH = ("the GitHub repository shamilmamedov/dynamic_calibration (git clone https://github.com/shamilmamedov/"
         "dynamic_calibration): pass its checkout as --data or set PHAST_UR10E_DATA")


def has_payload(name: str) -> bool:
    """A run recorded with a payload at the flange: 'load' in its name, except 'unload'."""
    low = name.lower()
    return "load" in low.replace("unload", "")


def find_runs(data: Path, holdout: tuple[str, ...], max_runs: int | None,
              payload: bool = False) -> tuple[list[Path], list[Path], list[str]]:
    """(training runs, held-out runs, runs left out with the reason): identification runs without a payload (with
    ``payload``, all of them), the held-out ones by name from identification_data/ or validation_data/."""
    ident = sorted((data / DATASET / "identification_data").glob("*.csv"))
    valid = sorted((data / DATASET / "validation_data").glob("*.csv"))
    by_name = {p.stem: p for p in ident + valid}
    missing = [h for h in holdout if h not in by_name]
    if missing:
        raise ValueError(f"held-out runs {missing} not found in {data / DATASET}/identification_data or validation_data")
    held = [by_name[h] for h in holdout]
    left = [] if payload else [f"{p.name}: payload" for p in ident if has_payload(p.stem)]
    train = [p for p in ident if (payload or not has_payload(p.stem)) and p.stem not in holdout]
    if max_runs is not None:
        left += [f"{p.name}: beyond --max-runs {max_runs}" for p in train[max_runs:]]
        train = train[:max_runs]
    return train, held, left


def read_run(path: Path, gains: np.ndarray, max_seconds: float | None, every: int) -> dict[str, Any]:
    """One log as published: t, q, u = gains x current (rows as they come, truncated ones NaN, counted)."""
    from phast_model.identify.logs import read_rows

    table = read_rows(path, header=False)
    if table.values.shape[1] < I_COLS.stop:
        raise ValueError(f"{path}: rows of {table.values.shape[1]} values; a UR10e log has 19 or 31 (t, q, qd, i, ...)")
    rows = np.arange(len(table.values))
    if max_seconds is not None:
        steps = np.diff(table.values[:, T_COL])
        dt = float(np.median(steps[np.isfinite(steps) & (steps > 0)]))
        rows = rows[: int(round(max_seconds / dt)) + 1]
    rows = rows[::every]
    v = table.values[rows]
    return {"q": v[:, Q_COLS], "t": v[:, T_COL], "u": v[:, I_COLS] * gains, "truncated": int(table.truncated[rows].sum()),
            "rows": int(len(table.values))}


def log_set(runs: list[Path], gains: np.ndarray, max_seconds: float | None, every: int) -> dict[str, Any]:
    """The runs as a log set (docs/mismatch.md: q_k, t_k, u_k, log_names, rows_truncated, coordinate_names)."""
    out: dict[str, Any] = {}
    for k, path in enumerate(runs):
        run = read_run(path, gains, max_seconds, every)
        out.update({f"q_{k}": run["q"], f"t_{k}": run["t"], f"u_{k}": run["u"]})
        out.setdefault("rows_truncated", []).append(run["truncated"])
    out["log_names"] = np.array([p.name for p in runs])
    out["rows_truncated"] = np.array(out["rows_truncated"], dtype=int)
    out["coordinate_names"] = np.array(JOINTS)
    return out


def gains_from(args: argparse.Namespace) -> np.ndarray:
    """The drive gains x the current scale; ValueError naming a bad option."""
    gains = DRIVE_GAINS
    if args.drive_gains is not None:
        try:
            gains = tuple(float(g) for g in json.loads(args.drive_gains))
        except (json.JSONDecodeError, TypeError, ValueError):
            raise ValueError(f"--drive-gains must be a JSON list of 6 numbers, got {args.drive_gains!r}") from None
    if len(gains) != 6 or not all(math.isfinite(g) for g in gains):
        raise ValueError(f"--drive-gains must be 6 finite numbers (one per joint), got {list(gains)}")
    if not (math.isfinite(args.current_scale) and args.current_scale > 0):
        raise ValueError(f"--current-scale must be a positive number, got {args.current_scale}")
    return np.array(gains) * args.current_scale


#: the identified model in the repository
PARAMETERS = Path("UR10E_parameters.txt")
#: [kg m^2] added to every principal moment of the authors' links (MuJoCo refuses a zero moment)
ROD_MOMENT = 1e-6


def published_vectors(text: str) -> dict[str, np.ndarray]:
    """``name = [v1 v2 ...]`` lines of UR10E_parameters.txt -> {name: values}."""
    out = {}
    for line in text.splitlines():
        name, sep, rest = line.partition("=")
        if sep and rest.strip().startswith("[") and rest.strip().endswith("]"):
            out[name.strip()] = np.array([float(v) for v in rest.strip()[1:-1].split()])
    missing = {"pi_rgd": 60, "pi_drvs": 6, "pi_frcn": 18}
    bad = [k for k, size in missing.items() if k not in out or out[k].size != size]
    if bad:
        raise ValueError(f"{PARAMETERS}: expected {missing}, could not read {bad}")
    return out


def link_inertial(pi: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """One link's (mass, centre of mass, full inertia [Ixx Iyy Izz Ixy Ixz Iyz] about it) from the authors' 10
    standard parameters [Ixx Ixy Ixz Iyy Iyz Izz] about the link frame's origin, m c, m (their parse_urdf.m)."""
    m, c = float(pi[9]), pi[6:9] / pi[9]
    about_origin = np.array([[pi[0], pi[1], pi[2]], [pi[1], pi[3], pi[4]], [pi[2], pi[4], pi[5]]])
    at_com = about_origin - m * (float(c @ c) * np.eye(3) - np.outer(c, c))  # parallel-axis theorem
    at_com += ROD_MOMENT * np.eye(3)  # some of their links are rods (a zero principal moment): MuJoCo needs > 0
    return m, c, np.array([at_com[0, 0], at_com[1, 1], at_com[2, 2], at_com[0, 1], at_com[0, 2], at_com[1, 2]])


def authors_parameters(data: Path) -> dict[str, np.ndarray]:
    """The authors' identified model as published (``UR10E_parameters.txt`` in the checkout ``data``)."""
    return published_vectors((data / PARAMETERS).read_text(encoding="utf-8", errors="replace"))


def authors_drives(vec: dict[str, np.ndarray]) -> list[dict[str, float]]:
    """Per joint, the authors' drive as MuJoCo attributes: rotor inertia ``pi_drvs`` as ``armature``, viscous Fv as
    ``damping``, Coulomb Fc as ``frictionloss`` (their constant offset per joint has no attribute)."""
    friction = vec["pi_frcn"].reshape(6, 3)  # per joint: Fv, Fc, offset
    return [{"armature": float(vec["pi_drvs"][k]), "damping": float(friction[k, 0]),
             "frictionloss": float(friction[k, 1])} for k in range(6)]


def urdf_model(data: Path, drives: list[dict[str, float]], path: Path, links: np.ndarray | None = None) -> Path:
    """The published URDF written as MJCF to ``path``, with ``drives`` (per joint: attribute -> value) and, given
    ``links`` (the authors' ``pi_rgd``: 10 values per link, the link each joint moves, in joint order), those link
    parameters in place of the URDF's."""
    from phast_gym.systems.mjcf_tree import urdf_spec
    from phast_model.identify.mjcf_write import set_joint_attr

    spec = urdf_spec((data / URDF).read_text())
    for k, name in enumerate(JOINTS):
        joint = spec.joint(name)
        if links is not None:
            body = joint.parent
            body.mass, body.ipos, body.fullinertia = link_inertial(links[10 * k: 10 * k + 10])
            body.explicitinertial = True
        for attr, value in drives[k].items():
            set_joint_attr(joint, attr, value)
    spec.compile()
    path.write_text(spec.to_xml())
    return path


def authors_model(data: Path, out: Path) -> Path:
    """The authors' identified model as MJCF, ``OUT/authors_model.xml``: their link parameters (about each URDF link
    frame; rod-like links get :data:`ROD_MOMENT` on each principal moment) and their drives (:func:`authors_drives`)."""
    vec = authors_parameters(data)
    return urdf_model(data, authors_drives(vec), out / "authors_model.xml", vec["pi_rgd"])


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", default=os.environ.get("PHAST_UR10E_DATA"), help="checkout of shamilmamedov/dynamic_calibration")
    p.add_argument("--out", required=True, help="output folder: recordings.npz, runs.json, report/")
    p.add_argument("--drive-gains", default=None, help=f"JSON list of 6 drive gains [N m / A] (default the authors' {list(DRIVE_GAINS)})")
    p.add_argument("--current-scale", type=float, default=1.0, help="one factor on every drive gain (default 1)")
    p.add_argument("--holdout", default=",".join(HOLDOUT), help="comma-separated run names (file stems) held out")
    p.add_argument("--max-runs", type=int, default=None, help="at most this many training runs (in name order)")
    p.add_argument("--max-seconds", type=float, default=None, help="the first S seconds of each run")
    p.add_argument("--every", type=int, default=1, help="keep every K-th row (u then holds over K rows: a smoke run)")
    p.add_argument("--rollout-window", type=float, default=1.0, help="held-out open-loop windows [s] (default 1)")
    p.add_argument("--threads", type=int, default=1, help="MuJoCo threads for the analysis' rollouts (default 1)")
    p.add_argument("--quick", action="store_true", help=f"a smoke run in minutes: {QUICK}")
    p.add_argument("--no-compare", action="store_true",
                   help="do not score the authors' identified model (UR10E_parameters.txt written as MJCF, "
                        "OUT/authors_model.xml) beside the tool's answer")
    p.add_argument("--convert-only", action="store_true", help="write recordings.npz and runs.json, run no analysis")
    p.add_argument("--world-model", action="store_true",
                   help="after the analysis, train PHAST PARTIAL on the same runs (phast-train at its defaults, "
                        "OUT/world_model/) and score it beside calibrated.xml and the authors' model")
    p.add_argument("--with-payload", action="store_true",
                   help="read the payload runs too (to see every run through the loader; the URDF has no payload)")
    return p


def convert(args: argparse.Namespace, data: Path, out: Path) -> tuple[dict[str, Any], Path, list[int]]:
    """Read the runs, write OUT/recordings.npz and OUT/runs.json; (the facts, the recordings' path, held-out indices)."""
    from phast_model.identify.recordings import load_raw, validate
    from phast_model.identify.simulators import load_simulator

    holdout = tuple(h.strip() for h in args.holdout.split(",") if h.strip())
    train, held, left = find_runs(data, holdout, args.max_runs, args.with_payload)
    gains = gains_from(args)
    raw = log_set(train + held, gains, args.max_seconds, args.every)
    path = out / "recordings.npz"
    np.savez(path, **raw)
    system = load_simulator(str(data / URDF)).build()
    loaded, src = load_raw(path)
    rec = validate(loaded, system.n, tuple(system.angle_dims), src, actuated_dofs=getattr(system, "actuated_dofs", None), model=system)
    logs = rec.meta["logs"]
    facts = {"data": str(data), "urdf": str(data / URDF), "drive_gains": gains.tolist(), "train": [p.name for p in train],
             "held_out": [p.name for p in held], "left_out": left, "max_seconds": args.max_seconds, "every": args.every,
             "rows": dict(zip(logs["names"], logs["rows"])), "rows_dropped": logs["rows_dropped"],
             "rows_dropped_per_log": dict(zip(logs["names"], logs["rows_dropped_per_log"])), "pieces": logs["n_pieces"],
             "piece_samples": logs["piece_samples"], "dt": rec.dt, "note": logs["note"],
             "joint_limits_reached": rec.meta.get("joint_limits_reached", [])}
    (out / "runs.json").write_text(json.dumps(facts, indent=1))
    return facts, path, list(range(len(train), len(train) + len(held)))


def analyse(args: argparse.Namespace, data: Path, recordings: Path, holdout: list[int], out: Path) -> dict[str, Any]:
    """phast-mismatch on the URDF as published; the headline numbers of its report."""
    from phast_model.cli.mismatch import main as mismatch

    start = time.time()
    compare = []
    if not args.no_compare:
        try:
            compare = ["--compare", f"authors={authors_model(data, out)}"]
        except (OSError, ValueError) as exc:  # the answer does not depend on it: say so and go on
            print(f"[ur10e] the authors' model is not scored: {exc}", file=sys.stderr)
    rc = mismatch(["--sim", str(data / URDF), "--recordings", str(recordings), "--holdout-trajectories",
                   ",".join(str(k) for k in holdout), "--rollout-window", str(args.rollout_window), *compare,
                   "--threads", str(args.threads),
                   "--out", str(out / "report")])
    wall = time.time() - start
    if rc != 0:
        return {"exit_status": rc, "wall_time_s": wall}
    report = json.loads((out / "report" / "report.json").read_text())
    return {"exit_status": rc, "wall_time_s": wall, "chi2_per_dof": report["details"]["chi2_per_dof"],
            "fit": {k: v for k, v in report["fit"].items() if isinstance(v, dict) and "rollout_rmse" in v},
            "missing_physics": [f"{m['term']} on {m.get('joint', m['coordinate'])}" for m in report["missing_physics"]],
            "summary": report["summary"]}


def world_model(args: argparse.Namespace, data: Path, recordings: Path, holdout: list[int], out: Path) -> dict[str, Any]:
    """phast-train PARTIAL on the URDF at its defaults, the MJCF files of the analysis scored on its held-out windows
    by the same code; the headline numbers of its metrics.json."""
    from phast_model.cli.train import main as train

    compare = [f"{name}={path}" for name, path in (("calibrated", out / "report" / "calibrated.xml"),
                                                   ("authors", out / "authors_model.xml")) if path.is_file()]
    start = time.time()
    rc = train(["--recordings", str(recordings), "--sim", str(data / URDF), "--regime", "partial",
                "--holdout-trajectories", ",".join(str(k) for k in holdout), "--rollout-window-s",
                str(args.rollout_window), "--threads", "1", *[a for c in compare for a in ("--compare", c)],
                "--out", str(out / "world_model")])
    wall = time.time() - start
    if rc != 0:
        return {"exit_status": rc, "wall_time_s": wall}
    m = json.loads((out / "world_model" / "metrics.json").read_text())
    h = m["heldout"]
    return {"exit_status": rc, "wall_time_s": wall, "train_wall_time_s": m["train_wall_time_s"],
            "epochs_run": m["epochs_run"], "heldout_rmse": {k: v["rollout_rmse"] for k, v in h.items()
                                                            if isinstance(v, dict) and "rollout_rmse" in v},
            "over_nominal": {k[: -len("_over_nominal")]: v for k, v in h.items() if k.endswith("_over_nominal")},
            "verdict": m["verdict"]["message"]}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.quick:
        args.max_runs = QUICK["max_runs"] if args.max_runs is None else args.max_runs
        args.max_seconds = QUICK["max_seconds"] if args.max_seconds is None else args.max_seconds
        args.holdout = ",".join(QUICK["holdout"]) if args.holdout == ",".join(HOLDOUT) else args.holdout
    data = Path(args.data) if args.data else None
    if data is None or not (data / DATASET).is_dir() or not (data / URDF).is_file():
        print(f"real_ur10e_mismatch: error: UR10e data not found at {data}; it is {FETCH}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    try:
        if args.every < 1:
            raise ValueError(f"--every must be a positive integer, got {args.every}")
        facts, recordings, holdout = convert(args, data, out)
    except ValueError as exc:
        print(f"real_ur10e_mismatch: error: {exc}", file=sys.stderr)
        return 2
    print(f"[ur10e] training runs ({len(facts['train'])}): {', '.join(facts['train'])}")
    print(f"[ur10e] held out ({len(facts['held_out'])}): {', '.join(facts['held_out'])}; left out: {len(facts['left_out'])}")
    print(f"[ur10e] {facts['note']}")
    for name, dropped in facts["rows_dropped_per_log"].items():
        if any(dropped.values()):
            print(f"[ur10e]   {name}: {dropped}")
    if facts["joint_limits_reached"]:
        print(f"[ur10e] joint limits reached: {facts['joint_limits_reached']}")
    if args.convert_only:
        print(f"[ur10e] wrote {recordings} and {out / 'runs.json'}")
        return 0
    result = analyse(args, data, recordings, holdout, out)
    (out / "headline.json").write_text(json.dumps(result, indent=1))
    print(f"[ur10e] phast-mismatch exit {result['exit_status']} in {result['wall_time_s']:.0f} s; "
          f"chi2/dof {result.get('chi2_per_dof')}")
    if args.world_model:
        result["world_model"] = world_model(args, data, recordings, holdout, out)
        (out / "headline.json").write_text(json.dumps(result, indent=1))
        wm = result["world_model"]
        print(f"[ur10e] phast-train exit {wm['exit_status']} in {wm['wall_time_s']:.0f} s; held-out over the URDF's: "
              f"{wm.get('over_nominal')}")
        if wm["exit_status"] != 0:
            return int(wm["exit_status"])
    return int(result["exit_status"])


if __name__ == "__main__":
    sys.exit(main())
