"""phast-mismatch: locate and explain the mismatch between a simulator and recordings (docs/mismatch.md).

    phast-mismatch --sim PHAST/Pendulum-v0 [--sim-kwargs '{"length": 0.9}'] \\
                   --recordings recordings.npz [--holdout-fraction 0.3 | --holdout-trajectories 4,5] --out report_dir/

--out must be a new or empty directory, or a previous phast-mismatch report (which is replaced); anything else is
refused, so the tool never deletes files it did not write.

Exit status: 0 with a report; 2 for bad input (the message names the problem); 1 when the tool itself fails on valid
input (a bug: the traceback is written to ``error.log`` in the report directory, please report it).
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from phast_model.identify.recordings import Recordings


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="phast-mismatch", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sim", required=True,
                   help="nominal simulator: an env id (PHAST/Pendulum-v0), my_pkg.mod:MyRig or path/to/rig.py:MyRig "
                        "(a phast_gym.systems.System subclass), or a MuJoCo model file robot.xml / robot.urdf "
                        "(the report then also holds calibrated.xml; docs/robot_models.md)")
    p.add_argument("--sim-kwargs", default="{}", help="JSON dict of physical parameters overriding the simulator's")
    p.add_argument("--recordings", required=True,
                   help=".npz or .csv recordings, or a folder of .csv logs (keys / columns of docs/mismatch.md); logs "
                        "of different lengths are cut into equal pieces, bad rows dropped and counted (report.json "
                        "data.logs)")
    p.add_argument("--holdout-fraction", type=float, default=0.3,
                   help="share of trajectories (of logs, for logs of different lengths; of time, for one) held out")
    p.add_argument("--holdout-trajectories", default=None,
                   help="comma-separated 0-based trajectory indices to hold out, e.g. 4,5 (overrides "
                        "--holdout-fraction); "
                        "for logs of different lengths, log indices: every piece of a held-out log is held out")
    p.add_argument("--out", required=True, help="report directory (report.json, report.md, report.html, PNG plots)")
    p.add_argument("--threshold", type=float, default=5.0, help="significance a term must reach (|coefficient|/std)")
    p.add_argument("--max-terms", type=int, default=5, help="most terms to add")
    p.add_argument("--shoot-window", type=int, default=None, help="shooting window in samples (default: half a period)")
    p.add_argument("--smoothing-window", type=int, default=None,
                   help="Savitzky-Golay window in samples (seeds, residual map)")
    p.add_argument("--rollout-window", type=float, default=None,
                   help="held-out open-loop window in seconds (default: each held-out trajectory whole)")
    p.add_argument("--systematic-chi2", type=float, default=3.0,
                   help="shooting chi^2/dof above which model error dominates: parameters, armature and friction law "
                        "from the weak form")
    p.add_argument("--free", default="",
                   help="comma-separated parameters to calibrate although the simulator declares them "
                                               "known (Param(known=True), e.g. gravity): --free gravity")
    p.add_argument("--compare", action="append", default=[], metavar="NAME=MODEL",
                   help="one more model scored on the held-out recordings by the same code, as fit.NAME: a MuJoCo "
                        "model file (simulated by MuJoCo), e.g. a published identification written as MJCF; repeat "
                        "for more")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--threads", type=int, default=1,
                   help="native MuJoCo threads for a model file's rollouts (default 1; the answer does not depend on "
                        "it)")
    return p


def parse_indices(text: str | None) -> list[int] | None:
    """``"4,5"`` -> [4, 5]; anything but comma-separated integers is a ValueError naming the bad item."""
    if text is None:
        return None
    items = [s.strip() for s in text.split(",")]
    out = []
    for item in items:
        try:
            out.append(int(item))
        except ValueError:
            raise ValueError(f"--holdout-trajectories: {item!r} is not an integer (give 0-based indices, e.g. "
                             "4,5)") from None
    return out


def check_args(args: argparse.Namespace) -> None:
    """Numeric options in range, before any work; ValueError naming the option."""
    import math

    if not (math.isfinite(args.threshold) and args.threshold > 0):
        raise ValueError("--threshold must be a positive number (a significance |coefficient|/std), got "
                         f"{args.threshold}")
    if args.max_terms < 0:
        raise ValueError(f"--max-terms must be >= 0, got {args.max_terms}")
    if args.shoot_window is not None and args.shoot_window < 2:
        raise ValueError(f"--shoot-window must be at least 2 samples, got {args.shoot_window}")
    if args.smoothing_window is not None and args.smoothing_window < 5:
        raise ValueError("--smoothing-window must be at least 5 samples (a cubic Savitzky-Golay filter), got "
                         f"{args.smoothing_window}")
    if args.rollout_window is not None and not (math.isfinite(args.rollout_window) and args.rollout_window > 0):
        raise ValueError(f"--rollout-window must be a positive number of seconds, got {args.rollout_window}")
    if args.threads < 1:
        raise ValueError(f"--threads must be at least 1, got {args.threads}")
    if not (math.isfinite(args.systematic_chi2) and args.systematic_chi2 > 0):
        raise ValueError(f"--systematic-chi2 must be a positive number, got {args.systematic_chi2}")


def compared_models(items: list[str]) -> dict[str, Any]:
    """``--compare NAME=MODEL`` items -> {NAME: the model file as MuJoCo simulates it}; ValueError naming a bad item."""
    from pathlib import Path

    from phast_gym.systems.mjcf_tree import ModelFileError
    from phast_model.identify.mujoco_sim import mujoco_simulated
    from phast_model.identify.simulators import is_model_file

    out: dict[str, Any] = {}
    for item in items:
        name, sep, path = (x.strip() for x in item.partition("="))
        if not sep or not name or not is_model_file(path):
            raise ValueError(f"--compare {item!r}: expected NAME=path/to/model.xml (or .urdf)")
        if not Path(path).is_file():
            raise ValueError(f"--compare {item!r}: file {path!r} not found")
        try:
            out[name] = mujoco_simulated(path)
        except ModelFileError as exc:
            raise ValueError(f"--compare {item!r}: {exc}") from None
    return out


def write_error_log(out_dir: str) -> str:
    """The current exception's traceback in ``out_dir/error.log`` (atomically; beside the report files, never over
    anything else), or in the working directory when ``out_dir`` cannot take it.  Returns its path."""
    import traceback
    from pathlib import Path

    from phast_gym.fileio import atomic_write_text

    text = traceback.format_exc()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        path = out / "error.log"
        atomic_write_text(path, text)
    except OSError:
        path = Path("phast-mismatch-error.log").absolute()
        atomic_write_text(path, text)
    return str(path)


def checked_recordings(sim: str, recordings: str, kwargs: dict[str, Any]) -> str | Recordings:
    """For a MuJoCo model file: the recordings validated against its joints too (coordinate names, joint ranges:
    :mod:`phast_model.identify.coordinates`), as the analysis takes them; else the path (the analysis reads it)."""
    from phast_model.identify.recordings import load_raw, validate
    from phast_model.identify.simulators import is_model_file, load_simulator

    if not is_model_file(sim):
        return recordings
    try:
        system = load_simulator(sim, kwargs).build()
    except ValueError:
        return recordings  # the analysis names the problem
    raw, src = load_raw(recordings)
    return validate(raw, system.n, tuple(system.angle_dims), src, actuated_dofs=getattr(system, "actuated_dofs", None),
                    model=system)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from phast_model.cli.args import json_object
    from phast_model.identify.split import check_holdout_indices
    from phast_model.mismatch import Options, analyze
    from phast_model.mismatch.report.files import check_writable

    try:
        check_args(args)
        holdout = check_holdout_indices(parse_indices(args.holdout_trajectories))
        check_writable(args.out)
        kwargs = json_object(args.sim_kwargs, "--sim-kwargs")
        opts = Options().with_(threshold=args.threshold, max_terms=args.max_terms, shoot_window=args.shoot_window,
                               smoothing_window=args.smoothing_window, progress=not args.quiet,
                               rollout_window=args.rollout_window,
                               systematic_chi2=args.systematic_chi2, threads=args.threads,
                               free=tuple(x.strip() for x in args.free.split(",") if x.strip()))
        recordings = checked_recordings(args.sim, args.recordings, kwargs)
        report = analyze(args.sim, recordings, sim_kwargs=kwargs, holdout_fraction=args.holdout_fraction, options=opts,
                         holdout_trajectories=holdout, compare=compared_models(args.compare))
        out = report.write(args.out, plots=not args.no_plots)
    except ValueError as exc:
        print(f"phast-mismatch: error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - an internal failure: exit 1 with the traceback kept for the bug report
        log = write_error_log(args.out)
        print(f"phast-mismatch: internal error: {type(exc).__name__}: {exc}\n(a bug, not a problem with the input; "
              f"traceback in {log})", file=sys.stderr)
        return 1
    print(report.summary)
    print(f"report written to {out}/report.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
