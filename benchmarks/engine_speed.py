"""The simulation engines a fit could run on, measured at the batch sizes the fits use (issue: fits at MuJoCo's speed).

    python benchmarks/engine_speed.py [--out docs/mismatch_results/engine_speed.json]

For a model file (the 3-joint bench arm and the 6-joint spatial arm of ``phast_model/bench/mjcf_models``), simulates
B windows of 45 samples at dt = 0.01 s with random commands, and prints CPU seconds (one thread) of:

* ``numpy``: the fits' engine today, :func:`phast_model.identify.shooting.simulate_qv` (the system's rigid-body
  formulas batched over the windows, RK4 at the model's substep, 2 per sample here);
* ``mujoco_file``: ``mujoco.rollout`` with the file's own integrator and timestep (RK4, 1 ms: what ``calibrated.xml``
  means);
* ``mujoco_matched``: ``mujoco.rollout``, RK4 at the numpy engine's substep (the same number of steps);
* ``mujoco_euler``: ``mujoco.rollout``, semi-implicit Euler at the numpy engine's substep.

Each row also gives the ratio numpy / engine (above 1: the engine is faster) and the largest difference in q from
the numpy engine.  The fits' batches: (1 + 2n + P) x windows per linearization, 10-1000 windows per case.
"""

from __future__ import annotations

import argparse
import json
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

MODELS = Path(__file__).resolve().parents[1] / "phast_model" / "bench" / "mjcf_models"
DT, L = 0.01, 45


def _cpu(f: Any) -> tuple[Any, float]:
    t = time.process_time()
    out = f()
    return out, time.process_time() - t


def _mujoco(model: Any, q0: np.ndarray, v0: np.ndarray, u: np.ndarray, h: float, integrator: int) -> np.ndarray:
    from phast_model.identify.mujoco_sim import rollout_q

    model.opt.integrator = integrator
    return rollout_q(model, q0, v0, u, DT, L, timestep=h)


def measure(path: Path, batches: list[int]) -> list[dict[str, Any]]:
    import mujoco

    from phast_gym.systems.mjcf import mjcf_system
    from phast_model.identify.mujoco_sim import load_mjmodel
    from phast_model.identify.shooting import simulate_qv, substeps_for

    system = mjcf_system(path)()
    model = load_mjmodel(str(path))
    file_step, file_integrator = float(model.opt.timestep), int(model.opt.integrator)
    sub = int(substeps_for(system, DT))
    rows = []
    for B in batches:
        rng = np.random.default_rng(0)
        q0, v0 = rng.normal(0, 0.5, (B, system.n)), rng.normal(0, 0.5, (B, system.n))
        u = rng.normal(0, 0.3, (B, L, system.n))
        ref, t_np = _cpu(partial(simulate_qv, system, q0, v0, L, u, DT, sub))
        row: dict[str, Any] = {"model": path.stem, "joints": system.n, "windows": B, "numpy_s": t_np, "substeps": sub}
        for name, h, integ in (("mujoco_file", file_step, file_integrator),
                               ("mujoco_matched", DT / sub, int(mujoco.mjtIntegrator.mjINT_RK4)),
                               ("mujoco_euler", DT / sub, int(mujoco.mjtIntegrator.mjINT_EULER))):
            q, t = _cpu(partial(_mujoco, model, q0, v0, u, h, integ))
            row.update({f"{name}_s": t, f"{name}_ratio": t_np / max(t, 1e-12),
                        f"{name}_max_dq": float(np.max(np.abs(q - ref)))})
        rows.append(row)
        print(f"{path.stem:5s} B={B:5d}  numpy {t_np:7.3f} s | file RK4 {row['mujoco_file_s']:7.3f} s "
              f"(x{row['mujoco_file_ratio']:.2f}) | matched RK4 {row['mujoco_matched_s']:7.3f} s "
              f"(x{row['mujoco_matched_ratio']:.2f}) | Euler {row['mujoco_euler_s']:7.3f} s "
              f"(x{row['mujoco_euler_ratio']:.2f})", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batches", type=int, nargs="*", default=[20, 100, 500, 2000])
    ap.add_argument("--out", type=Path, default=None, help="write the rows as JSON")
    args = ap.parse_args(argv)
    rows = [r for m in ("arm3", "arm6") for r in measure(MODELS / f"{m}.xml", args.batches)]
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_suffix(".tmp")
        tmp.write_text(json.dumps(rows, indent=1) + "\n")
        tmp.replace(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
