"""How phast-mismatch scales with a robot's size: an n-joint arm as MJCF, recorded by MuJoCo, analysed end to end.

The arm alternates pitch and yaw hinges (a spatial chain, not a planar one), every joint has a motor, and "reality"
has a frictionloss on the second joint that the file leaves out.  Recordings: smooth random torques on top of
gravity compensation, q noise 0.002 rad.  Prints and writes the wall time against the issue's budgets (3-joint
<= 3 min, 6-joint with 40 x 1000 samples <= 10 min on the 2-core machine) and what was found.

    python benchmarks/mjcf_scale.py --joints 3 --n-traj 20 --T 500 --out /tmp/scale3
    python benchmarks/mjcf_scale.py --joints 6 --n-traj 40 --T 1000 --out /tmp/scale6
    python benchmarks/mjcf_scale.py --grid --out /tmp/scale_grid     # the scaling table: joints and samples

Each row also gives the CPU seconds spent in MuJoCo's rollouts, in every simulation (MuJoCo's and the numpy
engine's), and in the held-out scoring: which term dominates.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

LINK = 0.25  # m


def arm_xml(n: int, frictionloss: float = 0.0) -> str:
    """An n-link arm: link i is a 0.25 m rod of 1.0 - 0.1 i kg hanging from a pitch (even i) or yaw (odd i) hinge."""
    body = ""
    for i in reversed(range(n)):
        axis = "0 1 0" if i % 2 == 0 else "1 0 0"
        fl = f' frictionloss="{frictionloss}"' if i == 1 and frictionloss else ""
        m = 1.0 - 0.1 * i
        ixx = m * LINK**2 / 12
        inner = body
        body = (f'<body name="link{i + 1}" pos="0 0 {-LINK if i else 0}">'
                f'<joint name="j{i + 1}" type="hinge" axis="{axis}"{fl}/>'
                f'<inertial pos="0.01 0.005 {-LINK / 2}" mass="{m:.2f}" diaginertia="{ixx:.5f} {ixx + 1e-4:.5f} 1e-3"/>'
                f"{inner}</body>")
    motors = "".join(f'<motor name="m{i + 1}" joint="j{i + 1}"/>' for i in range(n))
    return (f'<mujoco model="arm{n}"><option timestep="0.001" integrator="RK4"><flag contact="disable"/></option>'
            f'<worldbody><body name="base" pos="0 0 2">{body}</body></worldbody><actuator>{motors}</actuator></mujoco>')


def record(path_real: str, n: int, n_traj: int, T: int, dt: float, seed: int) -> dict:
    """MuJoCo recordings of the real arm: smooth random torques (scaled per joint by the weight it carries)."""
    from phast_model.identify.mujoco_sim import rollout_q

    rng = np.random.default_rng(seed)
    q0 = rng.uniform(-0.4, 0.4, (n_traj, n))
    v0 = rng.uniform(-0.3, 0.3, (n_traj, n))
    scale = np.array([0.4 * sum(1.0 - 0.1 * k for k in range(i, n)) * LINK for i in range(n)])
    knots = rng.normal(0.0, 1.0, (n_traj, T // 25 + 2, n)) * scale
    t = np.arange(T - 1) / 25
    u = np.stack([np.stack([np.interp(t, np.arange(knots.shape[1]), knots[k, :, j]) for j in range(n)], -1)
                  for k in range(n_traj)])
    q = rollout_q(path_real, q0, v0, u, dt, T - 1)
    q = q + rng.normal(0.0, 0.002, q.shape)
    return {"q": q, "u": u, "dt": dt}


#: the scaling grid of ``--grid``: (joints, trajectories, samples each): joints 2-7 at 10^4 samples, then 10^4 to 10^5
#: samples on the 3-joint and 6-joint arms (40 x 1000 on six joints is the issue's scale case)
GRID = ((2, 20, 500), (3, 20, 500), (6, 20, 500), (7, 20, 500), (3, 40, 750), (3, 100, 1000), (6, 40, 1000),
        (6, 100, 1000))


class StageClock:
    """CPU seconds spent inside a few functions of the analysis (wrapped for the run, restored after): MuJoCo's
    rollouts, every simulation of a shooting fit (MuJoCo's or the numpy engine's), and the held-out scoring (which includes
    rollouts and fits of its own)."""

    def __init__(self) -> None:
        import phast_model.identify.mujoco_sim as mujoco_sim
        import phast_model.identify.shooting as shooting
        import phast_model.mismatch.evaluate as evaluate

        self.spots = {"mujoco_rollouts": (mujoco_sim, "rollout_q"), "shooting_simulation": (shooting, "simulate_qv"),
                      "held_out_scoring": (evaluate, "evaluate_models")}
        self.seconds = dict.fromkeys(self.spots, 0.0)
        self._saved: dict[str, object] = {}

    def _timed(self, name: str, f):  # noqa: ANN001, ANN202 - any function
        def wrapper(*a, **k):  # noqa: ANN002, ANN003, ANN202
            t = time.process_time()
            try:
                return f(*a, **k)
            finally:
                self.seconds[name] += time.process_time() - t
        return wrapper

    def __enter__(self) -> StageClock:
        for name, (mod, attr) in self.spots.items():
            self._saved[name] = getattr(mod, attr)
            setattr(mod, attr, self._timed(name, self._saved[name]))
        return self

    def __exit__(self, *exc: object) -> None:
        for name, (mod, attr) in self.spots.items():
            setattr(mod, attr, self._saved[name])


def run(n: int, n_traj: int, T: int, dt: float, seed: int, out: Path, threads: int = 1, quiet: bool = False) -> dict:
    """One arm end to end: recordings, the analysis (timed by stage), the report in ``out``; the row of scale.json."""
    from phast_model.mismatch import analyze

    with tempfile.TemporaryDirectory() as d:
        nominal, real = Path(d) / f"arm{n}.xml", Path(d) / f"arm{n}_real.xml"
        nominal.write_text(arm_xml(n))
        real.write_text(arm_xml(n, frictionloss=0.05))
        rec = record(str(real), n, n_traj, T, dt, seed)
        hold = list(range(n_traj - max(1, n_traj // 5), n_traj))
        t0, c0 = time.perf_counter(), time.process_time()
        with StageClock() as clock:
            report = analyze(str(nominal), rec, holdout_trajectories=hold, progress=not quiet, threads=threads)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        report.write(out)
    budget = 180.0 if n <= 3 else 600.0
    found = [{k: m.get(k) for k in ("term", "joint", "mjcf", "coefficient", "ci95")} for m in report.missing_physics]
    f = report.fit
    return {"joints": n, "n_traj": n_traj, "T": T, "samples": n_traj * T, "threads": threads, "wall_s": round(wall, 1),
            "cpu_s": round(cpu, 1), "budget_s": budget, "within_budget": wall <= budget,
            "stages_cpu_s": {k: round(v, 1) for k, v in clock.seconds.items()},
            "hidden": "frictionloss 0.05 on j2", "found": found,
            "right": [(m["term"], m["joint"]) for m in found] == [("coulomb_friction", "j2")],
            "engine_step": report.diagnostics.get("engine_step"),
            "heldout_rollout_rmse": {k: v["rollout_rmse"] for k, v in f.items()
                                     if isinstance(v, dict) and "rollout_rmse" in v}}


def grid(out: Path, threads: int, seed: int) -> list[dict]:
    """The :data:`GRID` rows, resumed from ``out/grid.json`` (rewritten after each row), and ``out/grid.png``."""
    from phast_gym.fileio import atomic_write_text

    path = out / "grid.json"
    rows = json.loads(path.read_text())["rows"] if path.is_file() else []
    done = {(r["joints"], r["n_traj"], r["T"]) for r in rows}
    for n, n_traj, T in GRID:
        if (n, n_traj, T) in done:
            continue
        rows.append(run(n, n_traj, T, 0.01, seed, out / f"arm{n}_{n_traj}x{T}", threads, quiet=True))
        print(json.dumps({k: rows[-1][k] for k in ("joints", "samples", "wall_s", "cpu_s", "stages_cpu_s", "right")}),
              flush=True)
        atomic_write_text(path, json.dumps({"command": "benchmarks/mjcf_scale.py --grid", "commit": _commit(),
                                            "rows": rows}, indent=1) + "\n")
    plot(rows, out / "grid.png")
    return rows


def _commit() -> str:
    from phast_model.train.provenance import code_commit

    return code_commit(short=True, dirty=True)


def plot(rows: list[dict], path: Path) -> None:
    """CPU seconds against joints (at 10^4 samples) and against samples (per arm), with each stage's share."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    base = sorted((r for r in rows if r["samples"] == 10_000), key=lambda r: r["joints"])
    for key, label in (("cpu_s", "total"), ("mujoco_rollouts", "MuJoCo rollouts"),
                       ("held_out_scoring", "held-out scoring")):
        a.plot([r["joints"] for r in base], [r[key] if key == "cpu_s" else r["stages_cpu_s"][key] for r in base],
               "o-", label=label)
    a.set(xlabel="joints (10^4 samples)", ylabel="CPU s (one thread)", title="against joints")
    a.legend()
    for n in sorted({r["joints"] for r in rows}):
        line = sorted((r for r in rows if r["joints"] == n), key=lambda r: r["samples"])
        if len(line) > 1:
            b.loglog([r["samples"] for r in line], [r["cpu_s"] for r in line], "o-", label=f"{n} joints")
    b.set(xlabel="samples (trajectories x length)", ylabel="CPU s (one thread)", title="against samples")
    b.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--joints", type=int, default=3)
    ap.add_argument("--n-traj", type=int, default=20)
    ap.add_argument("--T", type=int, default=500)
    ap.add_argument("--dt", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1, help="MuJoCo threads (default 1)")
    ap.add_argument("--grid", action="store_true", help=f"the scaling grid {GRID} (joints, trajectories, samples), "
                                                        "resumed from OUT/grid.json; a plot in OUT/grid.png")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.grid:
        grid(args.out, args.threads, args.seed)
        return 0
    out = run(args.joints, args.n_traj, args.T, args.dt, args.seed, args.out, args.threads)
    (args.out / "scale.json").write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
