"""The mismatch tool on a real two-motor arm: what did the frictionless model leave out at each joint?

Data: ``dfki_double_pendulum_c0.npz`` (DFKI underactuated-lab double pendulum, hardware design C.0,
system-identification runs): 9 runs of q (joint angles, relative coordinates), the logger's jittered time
stamps and the measured motor torques u.  It is not shipped with the package: ``--data PATH``, or
``$PHAST_REAL_DATA`` naming its directory (default: the project workspace's ``../shared/data/real/`` next to
the repository); a missing file is a clear error.

The nominal simulator is ``PHAST/DoublePendulum-v0`` in joint coordinates with the authors' published
**frictionless** link parameters (compound links: masses, centre-of-mass distances, inertias about the
joint axes).  The tool gets q, t and u only.  The authors' identified model (their friction law
``b qd + cf atan(100 qd)`` and rotor inertia behind the gear) is written below as a user-described rig
and evaluated on the held-out runs by the same code, for comparison.

    python examples/real_double_pendulum_mismatch.py --out real_arm_report [--json headline.json]
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
from phast_gym.systems import DoublePendulum, Param
from phast_gym.systems.base import NUMPY, Components

REPO = Path(__file__).resolve().parents[1]
#: directory of the real recordings: $PHAST_REAL_DATA, else the project workspace's data next to the repository
DATA_DIR = Path(os.environ.get("PHAST_REAL_DATA", REPO.parent / "shared" / "data" / "real"))
DEFAULT_DATA = DATA_DIR / "dfki_double_pendulum_c0.npz"
#: runs held out (0-based): one of each excitation (both motors, motor 2 only, motor 1 only)
DEFAULT_HOLDOUT = (2, 4, 6)
#: open-loop windows of the held-out comparison [s] (the arm is chaotic over its 6-7 s runs)
ROLLOUT_WINDOW_S = 1.0


class PublishedIdentifiedArm(DoublePendulum):
    """The authors' identified plant (their ``double_pendulum.model.plant``) in joint coordinates: the compound links,
    rotor inertia Ir behind the gear ratio gr (M11 += (gr^2 + 1) Ir, M12 += -gr Ir, M22 += gr^2 Ir) and joint friction
    b qd_i + cf_i atan(100 qd_i) (b through the base class's viscous ``b``)."""

    name = "dfki_identified_arm"
    PARAMS = {
        **DoublePendulum.PARAMS,
        "rotor_inertia": Param(0.0, "motor rotor inertia Ir [kg m^2]", "nonnegative"),
        "gear_ratio": Param(6.0, "gear ratio gr"),
        "cf1": Param(0.0, "Coulomb level of joint 1 in cf atan(100 qd) [N m]", "nonnegative"),
        "cf2": Param(0.0, "Coulomb level of joint 2 in cf atan(100 qd) [N m]", "nonnegative"),
    }

    def _mass(self, c: Any) -> tuple:
        m11, m12, m22 = super()._mass(c)
        ir, gr = self.rotor_inertia, self.gear_ratio
        return m11 + (gr * gr + 1.0) * ir, m12 - gr * ir, m22 + gr * gr * ir

    def mass_matrix(self, q: Components, xp: Any = NUMPY) -> tuple:
        m11, m12, m22 = self._mass(xp.cos(self._phi(q)))
        return ((m11, m12), (m12, m22 + 0.0 * q[0]))

    def rhs(self, q: Components, p: Components, u: Components | None, xp: Any = NUMPY) -> tuple[tuple, tuple]:
        v, f = super().rhs(q, p, u, xp)
        return v, (f[0] - self.cf1 * np.arctan(100.0 * v[0]), f[1] - self.cf2 * np.arctan(100.0 * v[1]))  # numpy (mismatch evaluation)

    def has_damping(self) -> bool:
        return True


def load(path: Path, max_T: int | None = None) -> tuple[dict[str, Any], dict[str, Any], dict[str, float]]:
    """Recordings dict (docs/mismatch.md keys: q, t, u, angle_dims; the first ``max_T`` samples of each run), the nominal env
    kwargs, and the identified parameters."""
    if not path.exists():
        raise ValueError(f"real double-pendulum data not found at {path}; pass --data or set PHAST_REAL_DATA to its directory")
    with np.load(path, allow_pickle=False) as z:
        names = [str(s) for s in z["published_names"]]
        nominal = dict(zip(names, (float(v) for v in z["published_nominal"])))
        identified = dict(zip(names, (float(v) for v in z["published_identified"])))
        cut = slice(0, max_T)
        rec = {"q": z["q"][:, cut], "t": z["t"][:, cut], "u": z["u"][:, cut], "angle_dims": z["angle_dims"]}
        coords = str(z["coordinates"])
    if coords != "relative":
        raise ValueError(f"{path}: expected joint ('relative') coordinates, the file says {coords!r}")
    return rec, links(nominal), identified


def links(p: dict[str, float]) -> dict[str, Any]:
    """DoublePendulum kwargs of the authors' link parameters (compound links, joint coordinates)."""
    return {"coordinates": "relative", "mass1": p["m1"], "mass2": p["m2"], "length1": p["l1"], "length2": p["l2"],
            "com1": p["r1"], "com2": p["r2"], "inertia1": p["I1"], "inertia2": p["I2"], "gravity": p["g"]}


def identified_system(p: dict[str, float]) -> PublishedIdentifiedArm:
    """The authors' identified model (b1 = b2 in model_3.0, one viscous ``b``)."""
    if p["b1"] != p["b2"]:
        raise ValueError(f"identified viscous friction differs per joint (b1={p['b1']}, b2={p['b2']}); the base class has one b")
    return PublishedIdentifiedArm(**links(p), b=p["b1"], rotor_inertia=p["Ir"], gear_ratio=p["gr"], cf1=p["cf1"], cf2=p["cf2"])


def run(data: Path = DEFAULT_DATA, out: Path | None = None, holdout: tuple[int, ...] = DEFAULT_HOLDOUT,
        rollout_window: float = ROLLOUT_WINDOW_S, progress: bool = True, max_T: int | None = None) -> dict[str, Any]:
    """Analyze the runs; returns headline numbers (and writes the report to ``out``)."""
    from phast_model.mismatch import analyze

    rec, kwargs, ident = load(Path(data), max_T)
    report = analyze("PHAST/DoublePendulum-v0", rec, sim_kwargs=kwargs, holdout_trajectories=list(holdout),
                     rollout_window=rollout_window, progress=progress,
                     compare={"published identified": identified_system(ident)})
    if out is not None:
        report.write(out)
    f = report.fit
    found = report.missing_physics
    published_level = {0: ident["cf1"] * math.pi / 2, 1: ident["cf2"] * math.pi / 2}
    coulomb = {m["coordinate"]: m for m in found if m["term"] == "coulomb_friction"}
    nominal_rmse, aug_rmse = f["nominal"]["rollout_rmse"], f["augmented"]["rollout_rmse"]
    return {
        "missing_physics": [{k: m.get(k) for k in ("term", "coordinate", "coefficient", "ci95")} for m in found],
        "coulomb_found_at_joints": sorted(coulomb),
        "coulomb_over_published_level": {f"joint {i + 1}": coulomb[i]["coefficient"] / published_level[i] for i in sorted(coulomb)},
        "published_coulomb_level_nm": {f"joint {i + 1}": v for i, v in published_level.items()},
        "heldout_rollout_rmse_rad": {k: f[k]["rollout_rmse"] for k in f if isinstance(f[k], dict) and "rollout_rmse" in f[k]},
        "augmented_over_nominal": aug_rmse / max(nominal_rmse, 1e-300),
        "identified_over_nominal": f["published identified"]["rollout_rmse"] / max(nominal_rmse, 1e-300),
        "held_out_runs": list(holdout),
        "rollout_window_s": f.get("rollout_window_s"),
        "every_ci_excludes_zero": all(m["ci95"] is not None and m["ci95"][0] * m["ci95"][1] > 0 for m in found),
        "noise_std_rad": report.data["noise_std"],
        "wall_time_s": report.details.get("wall_time_s"),
        "summary": report.summary,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="path to dfki_double_pendulum_c0.npz")
    ap.add_argument("--out", type=Path, default=Path("real_arm_report"), help="report directory")
    ap.add_argument("--holdout-trajectories", default=",".join(map(str, DEFAULT_HOLDOUT)),
                    help="held-out runs, 0-based indices (default: one of each excitation)")
    ap.add_argument("--rollout-window", type=float, default=ROLLOUT_WINDOW_S, help="held-out open-loop window [s]")
    ap.add_argument("--json", type=Path, default=None, help="also write the printed headline numbers to this JSON file")
    ap.add_argument("--max-T", type=int, default=None, help="use only the first samples of each run (faster)")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    args = ap.parse_args(argv)
    try:
        holdout = tuple(int(s) for s in args.holdout_trajectories.split(",") if s.strip())
        res = run(args.data, args.out, holdout, args.rollout_window, progress=not args.quiet, max_T=args.max_T)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json is not None:
        atomic_write_json(args.json, res, indent=1)
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
