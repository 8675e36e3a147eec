"""phast-mismatch-bench: concealed-effect "realities" from the env suite, the mismatch tool vs a PySINDy peer.

Each case simulates 40 trajectories x 400 steps of an env with hidden terms of
the vocabulary and/or changed parameters, adds q-noise, and hands the tool only
the nominal env id.  A case is right when the found term set (names and
coordinates) equals the hidden one, every coefficient is within 30%, clean and
parameter-only cases report nothing, a changed parameter is recovered within 5%,
and the augmented model's held-out rollout RMSE is <= 0.7x the calibrated one.

The PySINDy peer gets the same q-only data: pysindy's SmoothedFiniteDifference
for qdot and qddot, the residual force M(q) qddot - F_nominal, and STLSQ on a
library of the same named force / port terms (columns standardized), built from
the term registry (:func:`sindy_library`): a registered law is a column too.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

if TYPE_CHECKING:
    from phast_gym.systems import System
    from phast_model.mismatch import Report


@dataclass
class Case:
    """One concealed-effect reality."""

    name: str
    env_id: str
    terms: list[tuple] = field(default_factory=list)  # (term, coordinate, coefficient[, Stribeck velocity])
    params: dict[str, float] = field(default_factory=dict)  # true values of changed parameters
    noise: float = 0.01
    u_std: float = 0.0
    x0_scale: float = 1.0
    kind: str = "effect"  # effect | clean | param
    # the nominal simulator the tool is given (the CAD values)
    sim_kwargs: dict[str, float | str] = field(default_factory=dict)
    rollout_window: float | None = None  # held-out open-loop windows [s] (a chaotic arm: short windows)
    dt: float | None = None  # sampling step of the recordings [s] (default: the env's)


#: a two-motor arm in joint coordinates with compound links: the CAD values of the DFKI C.0 design
ARM: dict[str, Any] = {"coordinates": "relative", "mass1": 0.6417, "mass2": 0.5639, "length1": 0.2, "length2": 0.3,
       "com1": 0.2, "com2": 0.3213, "inertia1": 0.02671, "inertia2": 0.05388, "gravity": 9.81}
#: the same arm with every link parameter 3-8% off its CAD value (a real rig's datasheet errors)
ARM_OFF = {"mass1": ARM["mass1"] * 1.05, "mass2": ARM["mass2"] * 0.96, "com1": ARM["com1"] * 1.07,
           "com2": ARM["com2"] * 0.97, "inertia1": ARM["inertia1"] * 1.06, "inertia2": ARM["inertia2"] * 0.92}


CASES: list[Case] = [
    Case("pendulum_clean", "PHAST/Pendulum-v0", kind="clean"),
    Case("damped_pendulum_clean", "PHAST/DampedPendulum-v0", kind="clean"),
    Case("oscillator_u_clean", "PHAST/DampedOscillator-v0", u_std=1.0, kind="clean"),
    Case("cartpole_clean", "PHAST/WindyCartPole-v0", kind="clean"),
    Case("damped_pendulum_gamma", "PHAST/DampedPendulum-v0", params={"gamma": 0.44}, kind="param"),
    Case("oscillator_omega", "PHAST/DampedOscillator-v0", params={"omega": 1.06}, kind="param"),
    Case("rlc_capacitance", "PHAST/RLCCircuit-v0", params={"capacitance": 0.92}, kind="param"),
    Case("windy_pendulum_dd", "PHAST/WindyPendulum-v0", params={"dd": 0.6}, kind="param"),
    Case("pendulum_viscous", "PHAST/Pendulum-v0", [("viscous_damping", 0, 0.01)]),
    Case("pendulum_coulomb", "PHAST/Pendulum-v0", [("coulomb_friction", 0, 0.04)]),
    Case("damped_pendulum_coulomb", "PHAST/DampedPendulum-v0", [("coulomb_friction", 0, 0.1)]),
    Case("pendulum_quadratic_drag", "PHAST/Pendulum-v0", [("quadratic_drag", 0, 0.005)]),
    Case("pendulum_position_damping", "PHAST/Pendulum-v0", [("position_dependent_damping", 0, 0.02)]),
    Case("damped_pendulum_linear_stiffness", "PHAST/DampedPendulum-v0", [("linear_stiffness", 0, 0.3)]),
    Case("oscillator_cubic_stiffness", "PHAST/DampedOscillator-v0", [("cubic_stiffness", 0, 0.03)]),
    Case("damped_pendulum_constant_force", "PHAST/DampedPendulum-v0", [("constant_force", 0, 0.2)]),
    Case("oscillator_actuator_gain", "PHAST/DampedOscillator-v0", [("actuator_gain", 1, 0.85)], u_std=1.0),
    Case("rlc_actuator_deadzone", "PHAST/RLCCircuit-v0", [("actuator_deadzone", 0, 0.4)], u_std=1.0),
    Case("damped_pendulum_sensor_offset", "PHAST/DampedPendulum-v0", [("sensor_offset", 0, 0.05)]),
    Case("oscillator_coulomb_q1", "PHAST/DampedOscillator-v0", [("coulomb_friction", 1, 0.03)]),
    Case("cartpole_cart_coulomb", "PHAST/WindyCartPole-v0", [("coulomb_friction", 0, 0.3)]),
    Case("two_effects_pendulum", "PHAST/DampedPendulum-v0", [("coulomb_friction", 0, 0.1), ("constant_force", 0, 0.2)]),
    Case("oscillator_stribeck", "PHAST/DampedOscillator-v0",
         [("coulomb_friction", 0, 0.02), ("stribeck_friction", 0, 0.04, 0.5)]),
    # parameters before terms (docs/mismatch_claims.md): parameter errors must not become terms
    Case("arm_inertia2", "PHAST/DoublePendulum-v0", params={"inertia2": ARM["inertia2"] * 1.1}, noise=0.002, u_std=0.5,
         kind="param", sim_kwargs=ARM, rollout_window=1.0),
    Case("arm_cad_off_coulomb", "PHAST/DoublePendulum-v0", [("coulomb_friction", 1, 0.08)], params=ARM_OFF, noise=0.002,
         u_std=0.5, sim_kwargs=ARM, rollout_window=1.0),
    Case("pendulum_port_gain", "PHAST/Pendulum-v0", [("actuator_gain", 0, 0.8)], noise=0.002, u_std=1.0),
    Case("pendulum_viscous_and_drag", "PHAST/Pendulum-v0",
         [("viscous_damping", 0, 0.003), ("quadratic_drag", 0, 0.001)], noise=0.002),
    Case("cartpole_pole_drag_cart_coulomb", "PHAST/WindyCartPole-v0",
         [("quadratic_drag", 1, 0.01), ("coulomb_friction", 0, 0.3)], noise=0.002),
    # delays: an actuator that acts 30 ms late at 100 Hz, a joint encoder that reports 10 ms late
    Case("pendulum_input_delay", "PHAST/Pendulum-v0", [("input_delay", 0, 0.03)], noise=0.002, u_std=1.0, dt=0.01),
    Case("arm_sensor_delay", "PHAST/DoublePendulum-v0", [("sensor_delay", 1, 0.01)], noise=0.002, u_std=0.5,
         sim_kwargs=ARM, rollout_window=1.0),
]


def _term_text(t: tuple) -> str:
    return f"{t[0]}[{t[1]}]={t[2]:g}" + (f"(v_s={t[3]:g})" if len(t) > 3 else "")


def run_tool(case: Case, rec: dict[str, Any], holdout: float) -> ToolResult:
    """The mismatch tool on one case, scored against the hidden truth."""
    from phast_model.mismatch import analyze

    t0, c0 = time.time(), time.process_time()
    rep = analyze(case.env_id, rec, sim_kwargs=case.sim_kwargs, holdout_fraction=holdout,
                  rollout_window=case.rollout_window)
    wall, cpu = time.time() - t0, time.process_time() - c0
    found = {(m["term"], m["coordinate"]): m["coefficient"] for m in rep.missing_physics}
    hidden = {(t[0], t[1]): t[2] for t in case.terms}
    coef_err = {f"{k[0]}[{k[1]}]": abs(found[k] - c) / abs(c) for k, c in hidden.items() if k in found}
    ok_terms = set(found) == set(hidden)
    ok_coef = ok_terms and all(v <= 0.3 for v in coef_err.values())
    fit = rep.fit
    ratio = fit["augmented"]["rollout_rmse"] / max(fit["calibrated"]["rollout_rmse"], 1e-300)
    param_err = {}
    scored = {} if case.terms and case.sim_kwargs else case.params  # CAD errors: only the combinations are identifiable
    for p, true in scored.items():
        cal = rep.sim["calibrated"].get(p)
        param_err[p] = abs(cal["fitted"] - true) / abs(true) if cal and cal.get("ci95") else float("inf")
    if case.kind == "effect":
        ok = ok_coef and ratio <= 0.7
    elif case.kind == "param":
        ok = not found and all(v <= 0.05 for v in param_err.values())
    else:
        ok = not found
    return {"found": sorted(f"{k[0]}[{k[1]}]={v:.4g}" for k, v in found.items()), "coef_rel_err": coef_err,
            "param_rel_err": param_err, "intervals": _intervals(rep, hidden, scored),
            "rollout_calibrated": fit["calibrated"]["rollout_rmse"],
            "rollout_augmented": fit["augmented"]["rollout_rmse"], "rollout_nominal": fit["nominal"]["rollout_rmse"],
            "ratio": ratio, "time_s": wall, "cpu_s": cpu, "correct": bool(ok), "summary": rep.summary}


class Interval(TypedDict):
    """A reported 95% interval against the truth (the bench's coverage column)."""

    what: str
    true: float
    estimate: float
    ci95: list[float]
    inside: bool
    rel_width: float  # the interval's width over |true|


class ToolResult(TypedDict):
    """The mismatch tool on one case, scored against the hidden truth."""

    found: list[str]
    coef_rel_err: dict[str, float]
    param_rel_err: dict[str, float]
    intervals: list[Interval]
    rollout_calibrated: float
    rollout_augmented: float
    rollout_nominal: float
    ratio: float
    time_s: float
    cpu_s: float
    correct: bool
    summary: str


class SindyResult(TypedDict):
    """The PySINDy peer on one case."""

    found: list[str]
    coef_rel_err: dict[str, float]
    correct: bool
    time_s: float


def _interval(what: str, true: float, estimate: float, ci95: list[float]) -> Interval:
    lo, hi = float(ci95[0]), float(ci95[1])
    return {"what": what, "true": true, "estimate": estimate, "ci95": [lo, hi], "inside": bool(lo <= true <= hi),
            "rel_width": (hi - lo) / abs(true)}


def _intervals(rep: Report, hidden: dict[tuple[str, int], float], scored: dict[str, float]) -> list[Interval]:
    """The reported 95% interval of every hidden coefficient the tool found (at its coordinate) and of every scored
    parameter change, with the truth and whether it lies inside: the bench's coverage column."""
    rows = {(m["term"], m["coordinate"]): m for m in rep.missing_physics}
    out = [_interval(f"{k[0]}[{k[1]}]", c, rows[k]["coefficient"], rows[k]["ci95"])
           for k, c in hidden.items() if k in rows and rows[k].get("ci95")]
    for p, true in scored.items():
        cal = rep.sim["calibrated"].get(p)
        if cal and cal.get("ci95"):
            out.append(_interval(p, true, cal["fitted"], cal["ci95"]))
    return out


def coverage(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """How many of the bench's reported 95% intervals hold the truth, and their median width relative to it."""
    items = [iv for r in rows for iv in r["tool"].get("intervals", [])]
    inside = sum(iv["inside"] for iv in items)
    return {"intervals": len(items), "inside": inside, "coverage": inside / len(items) if items else float("nan"),
            "median_rel_width": float(np.median([iv["rel_width"] for iv in items])) if items else float("nan")}


def run_sindy(case: Case, rec: dict[str, Any], threshold: float = 0.05) -> SindyResult:
    """PySINDy peer: own differentiation + STLSQ on the same named terms, residual to the nominal model (PySINDy's
    UserWarnings silenced for this call only)."""
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=UserWarning, module="pysindy")
        return _sindy_fit(case, rec, threshold)


def sindy_library(q: np.ndarray, v: np.ndarray, u: np.ndarray | None) -> dict[str, np.ndarray]:
    """The PySINDy peer's library on one coordinate: term name -> column, one per registered kind whose force is linear
    in its coefficient (:meth:`.registry.TermKind.regression_column`: forces at c = 1, sign(qdot) sharp; a velocity
    parameter, which STLSQ cannot profile, at its kind's fixed fraction of the rms speed: every grid column at once
    made STLSQ trade Coulomb against Stribeck on cases without either).  ``q``, ``v``, ``u`` the coordinate's samples
    (``u`` None when no input drives it).  Columns: the forces in vocabulary order, then those with a velocity, then
    the port terms."""
    from phast_model.mismatch.vocabulary.registry import VOCABULARY

    v_rms = float(np.sqrt(np.mean(v**2)))
    lib: dict[str, np.ndarray] = {}
    for kind in sorted(VOCABULARY.values(), key=lambda k: (k.component == "port", k.has_velocity)):
        col = kind.regression_column(q, v, u, v_rms)
        if col is not None:
            lib[kind.name] = col
    return lib


def _sindy_fit(case: Case, rec: dict[str, Any], threshold: float) -> SindyResult:
    import pysindy as ps

    from phast_gym.registry import make_env_system
    from phast_gym.systems.base import NUMPY
    from phast_model.identify.shooting import momentum
    from phast_model.mismatch.vocabulary.registry import VOCABULARY

    t0 = time.time()
    sys0 = make_env_system(case.env_id, **case.sim_kwargs)
    q = np.asarray(rec["q"], dtype=float)
    N, T, n = q.shape
    dt = float(rec["dt"])
    t = np.arange(T) * dt
    diff = ps.SmoothedFiniteDifference()
    v = np.stack([diff(q[k], t) for k in range(N)])
    a = np.stack([diff(v[k], t) for k in range(N)])
    u = None
    if "u" in rec:
        u = np.concatenate([rec["u"], rec["u"][:, -1:]], axis=1)
    p = momentum(sys0, q, v)
    if sys0.separable:  # constant M: pdot = M qddot
        pdot = momentum(sys0, q, a)
    else:  # d/dt (M(q) qdot) by differentiating p
        pdot = np.stack([diff(p[k], t) for k in range(N)])
    qc = tuple(q[..., i] for i in range(n))
    pc = tuple(p[..., i] for i in range(n))
    F = np.stack([np.broadcast_to(f, q.shape[:-1])
                  for f in sys0.rhs(qc, pc, None if u is None else tuple(u[..., i] for i in range(n)), NUMPY)[1]], -1)
    r = (pdot - F)[:, 5:-5].reshape(-1, n)
    found: dict[tuple[str, int], float] = {}
    for i in range(n):
        qi, vi = q[:, 5:-5, i].reshape(-1), v[:, 5:-5, i].reshape(-1)
        ui = u[:, 5:-5, i].reshape(-1) if u is not None and np.any(u[..., i] != 0) else None
        lib = sindy_library(qi, vi, ui)
        names = list(lib)
        Theta = np.stack([lib[k] for k in names], 1)
        scale = np.sqrt(np.mean(Theta**2, 0)) + 1e-12
        ri = r[:, i]
        rs = np.sqrt(np.mean(ri**2)) + 1e-12
        opt = ps.STLSQ(threshold=threshold, alpha=1e-6)
        opt.fit(Theta / scale, (ri / rs)[:, None])
        coef = np.asarray(opt.coef_).reshape(-1) * rs / scale
        for k, c in zip(names, coef):
            if c != 0:
                found[(k, i)] = float(c + VOCABULARY[k].default)  # a coefficient at no effect + the fitted change
    hidden = {(t[0], t[1]): t[2] for t in case.terms}
    coef_err = {f"{k[0]}[{k[1]}]": abs(found[k] - c) / abs(c) for k, c in hidden.items() if k in found}
    ok = set(found) == set(hidden) and all(e <= 0.3 for e in coef_err.values())
    return {"found": sorted(f"{k[0]}[{k[1]}]={v:.4g}" for k, v in found.items()), "coef_rel_err": coef_err,
            "correct": bool(ok), "time_s": time.time() - t0}


def reality_env(case: Case) -> str | type[System]:
    """The env the case's reality is simulated with: its env id, or at ``case.dt`` a subclass of its system sampled at
    that step (substeps no longer than the env's); the tool is given the env id."""
    if case.dt is None:
        return case.env_id
    import math

    from phast_gym.registry import make_env_system

    cls = type(make_env_system(case.env_id, **case.sim_kwargs))
    substeps = max(1, math.ceil(case.dt / (cls.dt / cls.substeps) - 1e-9))
    return type(f"{cls.__name__}At{case.dt:g}s", (cls,), {"dt": case.dt, "substeps": substeps})


def make_case_data(case: Case, n_traj: int, T: int, seed: int) -> dict[str, Any]:
    from phast_model.bench.reality import make_reality
    from phast_model.mismatch import Term

    return make_reality(reality_env(case), [Term(*t) for t in case.terms],
                        true_kwargs={**case.sim_kwargs, **case.params}, n_traj=n_traj, T=T, noise_std=case.noise,
                        seed=seed, u_std=case.u_std, x0_scale=case.x0_scale)


def effect_size(case: Case, n_traj: int, T: int, seed: int, window: int = 100) -> float:
    """RMS of q(reality) - q(nominal) over the first ``window`` samples (a plot's worth), in units of the q-noise.

    Same initial states and inputs, no noise: how far the hidden effect moves q
    in the time a person would look at; ~1 means buried in the noise.
    """
    from phast_model.bench.reality import make_reality
    from phast_model.mismatch import Term

    kw: dict[str, Any] = dict(n_traj=n_traj, T=min(T, window), noise_std=0.0, seed=seed, u_std=case.u_std,
                              x0_scale=case.x0_scale)
    a = make_reality(reality_env(case), [Term(*t) for t in case.terms], true_kwargs={**case.sim_kwargs, **case.params},
                     **kw)["q"]
    # a delay's reality starts earlier (its history): the same delay at 0 gives the same initial states and inputs
    zero = [Term(t[0], t[1], 0.0) for t in case.terms if Term(*t).kind.delay]
    b = make_reality(reality_env(case), zero, true_kwargs=case.sim_kwargs, **kw)["q"]
    d = a - b
    return float(np.sqrt(np.mean(d**2)) / case.noise)


def markdown_table(rows: list[dict[str, Any]]) -> str:
    """The bench rows as the markdown table of docs/mismatch.md (tool and, when run, the PySINDy peer)."""
    sindy = all("sindy" in r for r in rows)
    head = ["case", "kind", "hidden", "eff/noise", "found by the tool", "coef./param. error",
            "held-out rollout RMSE calibrated -> augmented", "CPU s", "right"] + (
                ["PySINDy found", "PySINDy right"] if sindy else [])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        tl = r["tool"]
        errs = list(tl["coef_rel_err"].values()) + list(tl["param_rel_err"].values())
        cells = [r["case"], r["kind"], ", ".join(r["hidden"]) or "-", f"{r['effect_over_noise_first_100_samples']:.1f}",
                 ", ".join(tl["found"]) or "-", f"{max(errs):.1%}" if errs else "-",
                 f"{tl['rollout_calibrated']:.4f} -> {tl['rollout_augmented']:.4f} ({tl['ratio']:.2f}x)",
                 f"{tl['cpu_s']:.1f}", "yes" if tl["correct"] else "no"]
        if sindy:
            cells += [", ".join(r["sindy"]["found"]) or "-", "yes" if r["sindy"]["correct"] else "no"]
        lines.append("| " + " | ".join(cells) + " |")
    n_ok = sum(r["tool"]["correct"] for r in rows)
    foot = (f"Tool: **{n_ok}/{len(rows)} cases right ({n_ok / max(len(rows), 1):.0%})**"
            + (f"; PySINDy peer: {sum(r['sindy']['correct'] for r in rows)}/{len(rows)}" if sindy else "")
            + f". Largest time per case: {max(r['tool']['cpu_s'] for r in rows):.1f} s CPU "
            f"({max(r['tool']['time_s'] for r in rows):.1f} s wall).")
    return "\n".join(lines) + "\n\n" + foot + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="phast-mismatch-bench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", default=None, help=f"case names (default: all): {[c.name for c in CASES]}")
    ap.add_argument("--n-traj", type=int, default=40)
    ap.add_argument("--T", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise-scale", type=float, default=1.0,
                    help="multiply every case's q-noise std (robustness sweeps; eff/noise then falls by the same "
                         "factor)")
    ap.add_argument("--holdout-fraction", type=float, default=0.3)
    ap.add_argument("--no-sindy", action="store_true", help="skip the PySINDy peer")
    ap.add_argument("--out", default=None, help="write the results as JSON here")
    ap.add_argument("--markdown", default=None,
                    help="write the results table as markdown here (the table of docs/mismatch.md)")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    from phast_gym.fileio import atomic_write_json, atomic_write_text

    names = {c.name for c in CASES}
    bad = sorted(set(args.cases or []) - names)
    if bad:
        print(f"phast-mismatch-bench: error: unknown case(s) {bad}; known: {sorted(names)}", file=sys.stderr)
        return 2
    if not (args.noise_scale > 0 and np.isfinite(args.noise_scale)):
        print(f"phast-mismatch-bench: error: --noise-scale must be a positive number, got {args.noise_scale}",
              file=sys.stderr)
        return 2
    cases = [replace(c, noise=c.noise * args.noise_scale) for c in CASES if not args.cases or c.name in args.cases]
    rows = []
    for k, case in enumerate(tqdm(cases, desc="mismatch bench", file=sys.stderr)):
        rec = make_case_data(case, args.n_traj, args.T, args.seed + k)
        row = {"case": case.name, "env_id": case.env_id, "kind": case.kind,
               "hidden": sorted(_term_text(t) for t in case.terms)
               + sorted(f"{p}={v:g}" for p, v in case.params.items()),
               "effect_over_noise_first_100_samples": effect_size(case, args.n_traj, args.T, args.seed + k),
               "tool": run_tool(case, rec, args.holdout_fraction)}
        if not args.no_sindy:
            row["sindy"] = run_sindy(case, rec)
        rows.append(row)
    hdr = (f"{'case':34s} {'hidden':38s} {'eff/noise':>9s} {'found (tool)':40s} {'coef err':>8s} {'calib':>7s} "
           f"{'augm':>7s} {'ratio':>5s} {'wall':>6s} {'cpu':>6s} ok")
    if not args.no_sindy:
        hdr += f" | {'found (PySINDy)':44s} ok"
    print(hdr)
    for r in rows:
        tl = r["tool"]
        ce = max(list(tl["coef_rel_err"].values()) + list(tl["param_rel_err"].values()) or [0.0])
        line = (f"{r['case']:34s} {', '.join(r['hidden']) or '-':38.38s} "
                f"{r['effect_over_noise_first_100_samples']:9.2f} {', '.join(tl['found']) or '-':40.40s} "
                f"{ce:8.3f} {tl['rollout_calibrated']:7.4f} {tl['rollout_augmented']:7.4f} {tl['ratio']:5.2f} "
                f"{tl['time_s']:6.1f} {tl['cpu_s']:6.1f} "
                f"{'Y' if tl['correct'] else 'N'}")
        if "sindy" in r:
            line += f" | {', '.join(r['sindy']['found']) or '-':44.44s} {'Y' if r['sindy']['correct'] else 'N'}"
        print(line)
    n_ok = sum(r["tool"]["correct"] for r in rows)
    print(f"tool: {n_ok}/{len(rows)} cases right ({n_ok / max(len(rows), 1):.0%}); "
          f"max time per case {max(r['tool']['time_s'] for r in rows):.1f} s wall, "
          f"{max(r['tool']['cpu_s'] for r in rows):.1f} s CPU")
    cov = coverage(rows)
    print(f"95% intervals: {cov['inside']}/{cov['intervals']} hold the truth ({cov['coverage']:.0%}); median width "
          f"{cov['median_rel_width']:.3g} x the true value")
    if not args.no_sindy:
        n_s = sum(r["sindy"]["correct"] for r in rows)
        print(f"PySINDy peer: {n_s}/{len(rows)} cases right ({n_s / max(len(rows), 1):.0%})")
    if args.markdown:
        atomic_write_text(args.markdown, markdown_table(rows))
    if args.out:
        atomic_write_json(args.out, {"command": " ".join(["phast-mismatch-bench"]
                                                         + (argv if argv is not None else sys.argv[1:])),
                                     "n_traj": args.n_traj, "T": args.T, "seed": args.seed,
                                     "noise_scale": args.noise_scale, "coverage": cov, "rows": rows}, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
