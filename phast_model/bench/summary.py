"""Aggregate run records into ``summary.csv`` and paper-shaped markdown tables.

* ``summary.csv``: one row per (env, model, metric): mean, std (population, ddof 0),
  n_seeds, params.
* ``tables.md``: a Table-4-shaped suite summary (best PHAST regime vs best baseline
  per benchmark, gain = best baseline / best PHAST, and our best PHAST / the paper's
  PHAST number), each PHAST regime next to the paper's (Tables 17-24), the N-body
  floor rule, the acceptance verdict per row, then one Table-17-24-shaped block per
  benchmark (every model, params, ours vs paper).
"""

from __future__ import annotations

import csv
import io
import math
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, TypeAlias, TypedDict

import numpy as np
from gymnasium.error import Error as GymError

from phast_gym import make_env_system
from phast_gym.fileio import atomic_write_text

from .paper import PAPER, PAPER_FULL_STATE, PaperRow

DISPLAY = {"phast-known": "PHAST (KNOWN)", "phast-partial": "PHAST (PARTIAL)", "phast-unknown": "PHAST (UNKNOWN)",
           "gru": "GRU", "lstm": "LSTM", "transformer": "Transformer", "s5": "S5", "linoss": "LinOSS",
           "dlinoss": "D-LinOSS", "vpt": "VPT", "dhnn": "DHNN"}


class GroupStats(TypedDict, total=False):
    """One (env, model) of :func:`aggregate` (total=False: a group not run reads as ``{}``)."""

    metrics: dict[str, tuple[float, float, int]]  # metric -> (mean, std, number of seeds)
    params: int
    seeds: list[int]
    wall_time_s: float  # mean over the seeds


#: (env, model) -> its :class:`GroupStats`
Aggregated: TypeAlias = dict[tuple[str, str], GroupStats]


def _group_key(rec: Mapping[str, Any]) -> tuple[str, str]:
    env = rec["env"] + (" (full state)" if rec.get("config", {}).get("full_state") else "")
    return env, rec["model"]


@cache
def _constant_damping(env_id: str) -> bool:
    """True when the env's true D does not depend on q (its damping R^2 is undefined)."""
    try:
        return make_env_system(env_id).constant_damping() is not None
    except GymError:  # an env this checkout does not register: keep its records as they are
        return False


def _metric_value(env_id: str, key: str, value: object) -> float | None:
    """A record's metric as it enters the mean: a finite float, NaN (for None), or None (left out).

    ``damping_r2`` is left out where the true D is constant: its denominator is then round-off (records written
    before :func:`phast_model.train.metrics.damping_scores` returned NaN there hold values like -1e12)."""
    if value is None:
        return float("nan")
    if not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        return None
    if key == "damping_r2" and _constant_damping(env_id):
        return None
    return float(value)


def aggregate(records: Sequence[Mapping[str, Any]]) -> Aggregated:
    """(env, model) -> {"metrics": {key: (mean, std, n)}, "params": int, "seeds": [...], "wall_time_s": mean}."""
    groups: dict[tuple[str, str], list[Mapping[str, Any]]] = defaultdict(list)
    for rec in records:
        if rec.get("status") != "failed" and isinstance(rec.get("metrics"), dict):
            groups[_group_key(rec)].append(rec)
    out: Aggregated = {}
    for key, recs in groups.items():
        vals: dict[str, list[float]] = defaultdict(list)
        for r in recs:
            for k, v in r["metrics"].items():
                x = _metric_value(r["env"], k, v)
                if x is not None:
                    vals[k].append(x)
        out[key] = {
            "metrics": {k: (float(np.mean(v)), float(np.std(v)), len(v)) for k, v in vals.items()},
            "params": int(recs[0].get("params", 0)), "seeds": sorted(int(r["seed"]) for r in recs),
            "wall_time_s": float(np.mean([r.get("wall_time_s", 0.0) for r in recs])),
        }
    return out


def summary_rows(agg: Aggregated) -> list[dict[str, str | float | int]]:
    rows: list[dict[str, str | float | int]] = []
    for (env, model), g in sorted(agg.items()):
        for metric, (mean, std, n) in sorted(g["metrics"].items()):
            rows.append({"env": env, "model": model, "metric": metric, "mean": mean, "std": std, "n_seeds": n,
                         "params": g["params"]})
    return rows


def write_summary_csv(agg: Aggregated, path: str | Path) -> Path:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=["env", "model", "metric", "mean", "std", "n_seeds", "params"])
    w.writeheader()
    for row in summary_rows(agg):
        w.writerow({**row, "mean": f"{row['mean']:.6g}", "std": f"{row['std']:.6g}"})
    path = Path(path)
    atomic_write_text(path, buf.getvalue())
    return path


def fmt(x: float | None) -> str:
    """Compact number: 3 significant digits, scientific below 1e-3."""
    if x is None or not math.isfinite(x):
        return "n/a"
    if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e4):
        return f"{x:.2e}"
    return f"{x:.4f}" if abs(x) < 0.01 else f"{x:.3f}"


def _ms(t: tuple[float, float, int] | tuple[float, float] | None) -> str:
    return "—" if t is None else f"{fmt(t[0])} ± {fmt(t[1])}"


def paper_row_for(env: str) -> PaperRow | None:
    if env.endswith(" (full state)"):
        return PAPER_FULL_STATE if env.startswith("PHAST/WindyPendulum-v0") else None
    return PAPER.get(env)


def best_of(agg: Aggregated, env: str, metric: str, pick: Callable[[str], bool]) -> tuple[str, tuple] | None:
    rows = [(m, g["metrics"][metric]) for (e, m), g in agg.items()
            if e == env and pick(m) and metric in g["metrics"] and math.isfinite(g["metrics"][metric][0])]
    return min(rows, key=lambda r: r[1][0]) if rows else None


def best_sides(agg: Aggregated, env: str, metric: str) -> tuple[tuple[str, tuple] | None, tuple[str, tuple] | None]:
    """(best PHAST regime, best baseline) of ``env`` on ``metric``, each (model, (mean, std, n)) or None."""
    return (best_of(agg, env, metric, lambda m: m.startswith("phast-")),
            best_of(agg, env, metric, lambda m: not m.startswith("phast-")))


def metric_for(env: str) -> str:
    """The row metric: the paper table's key; falls back to ``benchmark_metric`` for envs without a paper row."""
    row = paper_row_for(env)
    if row is not None:
        return row.metric
    from phast_model.train.metrics import benchmark_metric

    return benchmark_metric(env.replace(" (full state)", ""))


def resolve_metric(metric: str, available: set[str]) -> str:
    """``metric`` if measured, else the same rollout metric at the largest measured horizon (reduced grids)."""
    if metric in available or "_h" not in metric:
        return metric
    stem = metric.rsplit("_h", 1)[0]
    hs = [int(k.rsplit("_h", 1)[1]) for k in available if k.startswith(stem + "_h") and k.rsplit("_h", 1)[1].isdigit()]
    return f"{stem}_h{max(hs)}" if hs else metric


def env_metric(agg: Aggregated, env: str) -> str:
    """The row metric of ``env`` as measured in ``agg`` (see :func:`resolve_metric`)."""
    keys = {k for (e, _), g in agg.items() if e == env for k in g["metrics"]}
    return resolve_metric(metric_for(env), keys)


def markdown_tables(agg: Aggregated, title: str = "phast-bench results", note: str = "") -> str:
    """Table-4-shaped summary + per-benchmark tables (markdown)."""
    envs = list(dict.fromkeys(e for e, _ in sorted(
        agg, key=lambda k: (list(PAPER).index(k[0]) if k[0] in PAPER else 99, k))))
    lines = [f"# {title}", ""]
    if note:
        lines += [note, ""]
    lines += ["## Suite summary (paper Table 4 shape)", "",
              "Gain = best baseline / best PHAST (ours). Paper PHAST = the paper's best-PHAST number; "
              "ratio = ours / paper (<= 1 means we match or beat it). Mean ± std over the seeds shown.", "",
              "| benchmark | metric | best PHAST (ours) | best baseline (ours) | gain | PHAST beats baselines | "
              "paper PHAST | ours / paper | seeds |",
              "|---|---|---|---|---|---|---|---|---|"]
    for env in envs:
        metric = env_metric(agg, env)
        bp, bb = best_sides(agg, env, metric)
        paper = paper_row_for(env)
        pp = paper.best("phast-") if paper else None
        gain = f"{bb[1][0] / bp[1][0]:.3g}×" if bp and bb and bp[1][0] > 0 else "—"
        beats = "—" if not (bp and bb) else ("yes" if bp[1][0] < bb[1][0] else "**no**")
        comparable = paper is not None and metric == paper.metric
        ratio = f"{bp[1][0] / pp[1]:.3g}" if bp and pp and pp[1] > 0 and comparable else "—"
        seeds = sorted({n for g in (bp, bb) if g for n in [g[1][2]]})
        name = paper.benchmark if paper else env
        lines.append(
            f"| {name} | `{metric}` | {_ms(bp[1]) + ' (' + DISPLAY[bp[0]] + ')' if bp else '—'} | "
            f"{_ms(bb[1]) + ' (' + DISPLAY[bb[0]] + ')' if bb else '—'} | {gain} | {beats} | "
            f"{fmt(pp[1]) + ' (' + DISPLAY[pp[0]] + ')' if pp else '—'} | {ratio} | "
            f"{','.join(map(str, seeds)) or '—'} |")
    lines += regime_table(agg, envs)
    lines += floor_rule(agg, envs)
    lines += acceptance_table(agg, envs)
    for env in envs:
        metric = env_metric(agg, env)
        paper = paper_row_for(env)
        if paper is not None and metric != paper.metric:
            paper = None  # another metric than the paper's (e.g. shorter horizons): no paper comparison
        lines += ["", f"## {paper.benchmark if paper else env} — `{env}`, `{metric}`"
                  + (f" (paper {paper.table})" if paper else ""), "",
                  "| model | params (ours) | ours: mean ± std | n | params (paper) | paper: mean ± std | wall s/run |",
                  "|---|---|---|---|---|---|---|"]
        models = [m for (e, m) in agg if e == env]
        order = list(DISPLAY)
        for m in sorted(models, key=lambda m: order.index(m) if m in order else 99):
            g = agg[(env, m)]
            t = g["metrics"].get(metric)
            pr = paper.results.get(m) if paper else None
            paper_params = paper.params.get(m) if paper else None
            lines.append(f"| {DISPLAY.get(m, m)} | {g['params']:,} | {_ms(t)} | {t[2] if t else 0} | "
                         f"{f'{paper_params:,}' if paper_params else '—'} | {_ms(pr)} | {g['wall_time_s']:.0f} |")
    return "\n".join(lines) + "\n"


def regime_table(agg: Aggregated, envs: list[str]) -> list[str]:
    """Each PHAST regime next to the paper's number for the same regime (paper Tables 17-24): best-of-regimes
    alone hides the rows where one regime trails."""
    regimes = [m for m in DISPLAY if m.startswith("phast-")]
    head = " | ".join(f"{DISPLAY[m]} ours | paper | ours / paper" for m in regimes)
    lines = ["", "## Regime by regime (paper Tables 17-24)", "",
             "Mean over the seeds shown; ours / paper <= 1 means the regime matches or beats the paper's number "
             "for the same regime.", "", f"| benchmark | metric | {head} |",
             "|---|---|" + "---|---|---|" * len(regimes)]
    for env in envs:
        metric = env_metric(agg, env)
        paper = paper_row_for(env)
        same_metric = paper if paper is not None and metric == paper.metric else None  # the paper's row, if comparable
        cells = []
        for m in regimes:
            t = agg.get((env, m), {}).get("metrics", {}).get(metric)
            pr = same_metric.results.get(m) if same_metric is not None else None
            ratio = f"{t[0] / pr[0]:.3g}" if t and pr and pr[0] > 0 else "—"
            cells.append(f"{_ms(t)} | {_ms(pr)} | {ratio}")
        lines.append(f"| {paper.benchmark if paper else env} | `{metric}` | " + " | ".join(cells) + " |")
    return lines


#: rows judged by the first-step floor rule: their paper number lies below our env's information floor
FLOOR_RULE_ENVS = ("PHAST/NBody3-v0",)


@dataclass(frozen=True)
class FloorVerdict:
    """The N-body rule on one row: the best PHAST and best baseline (model, (mean, std, n)) on Eq. 90 and after the
    burn-in, against the information floor."""

    floor: float
    phast_eq90: tuple[str, tuple] | None
    phast_after: tuple[str, tuple] | None
    base_eq90: tuple[str, tuple] | None
    base_after: tuple[str, tuple] | None
    slack: float = 1.1

    @property
    def within(self) -> bool:
        return self.phast_eq90 is not None and self.phast_eq90[1][0] <= self.slack * self.floor

    @property
    def beats(self) -> bool:
        p90, pab, b90, bab = self.phast_eq90, self.phast_after, self.base_eq90, self.base_after
        if p90 is None or pab is None or b90 is None or bab is None:
            return False
        return p90[1][0] < b90[1][0] and pab[1][0] < bab[1][0]

    @property
    def passes(self) -> bool:
        return self.within and self.beats


def floor_verdict(agg: Aggregated, env: str, slack: float = 1.1) -> FloorVerdict:
    """The N-body rule's numbers for ``env`` (see :func:`floor_rule`)."""
    from .floor import first_step_floor

    (p90, b90), (pab, bab) = best_sides(agg, env, "mse"), best_sides(agg, env, "mse_after_burnin")
    return FloorVerdict(float(first_step_floor(env)["floor_mse"]), p90, pab, b90, bab, slack)


def floor_rule(agg: Aggregated, envs: list[str], slack: float = 1.1) -> list[str]:
    """N-body: the paper's next-step MSE is below the floor no causal model can avoid (the t = 0 prediction,
    :func:`phast_model.bench.floor.first_step_floor`).  The row passes when the best PHAST is within ``slack`` x the
    floor on Eq. 90 and beats every baseline both on Eq. 90 and on the next-step MSE after the burn-in."""
    rows = [e for e in envs if e in FLOOR_RULE_ENVS]
    if not rows:
        return []
    lines = ["", "## Next-step rows below the information floor (N-body rule)", "",
             "| benchmark | floor (Eq. 90) | best PHAST: Eq. 90 | after burn-in | best baseline: Eq. 90 "
             f"| after burn-in | within {slack:g}x floor | beats baselines on both | passes |",
             "|---|---|---|---|---|---|---|---|---|"]
    for env in rows:
        v = floor_verdict(agg, env, slack)

        def show(c: tuple | None) -> str:
            return "—" if c is None else f"{_ms(c[1])} ({DISPLAY.get(c[0], c[0])})"

        lines.append(f"| {_benchmark(env)} | {fmt(v.floor)} | {show(v.phast_eq90)} | {show(v.phast_after)} | "
                     f"{show(v.base_eq90)} | {show(v.base_after)} | {'yes' if v.within else 'no'} | "
                     f"{'yes' if v.beats else 'no'} | {'**yes**' if v.passes else 'no'} |")
    return lines


def _benchmark(env: str) -> str:
    row = paper_row_for(env)
    return row.benchmark if row else env


def acceptance_table(agg: Aggregated, envs: list[str], n_seeds: int | None = None) -> list[str]:
    """Each row judged as the grid's acceptance asks: complete (every model of the paper's grid over ``n_seeds``
    seeds, default the most any model has), the best PHAST beats the best baseline of the same run, and it matches
    or beats the paper's best PHAST (rows in ``FLOOR_RULE_ENVS``: the floor rule instead)."""
    from .spec import ALL_MODELS

    n = n_seeds or max((len(g["seeds"]) for g in agg.values() if "seeds" in g), default=0)
    lines = ["", "## Acceptance", "",
             f"A row passes when it is complete ({len(ALL_MODELS)} models x {n} seeds), its best PHAST beats its best "
             "baseline, and it matches or beats the paper's best PHAST (N-body: the floor rule above).", "",
             "| benchmark | complete | beats baselines | matches paper | passes |", "|---|---|---|---|---|"]
    verdicts = []
    for env in envs:
        missing = [m for m in ALL_MODELS if len(agg.get((env, m), {}).get("seeds", [])) < n]
        if env in FLOOR_RULE_ENVS:
            v = floor_verdict(agg, env)
            beats, matches, bb = v.beats, v.within, v.base_eq90
        else:
            metric = env_metric(agg, env)
            bp, bb = best_sides(agg, env, metric)
            paper = paper_row_for(env)
            pp = paper.best("phast-") if paper is not None and paper.metric == metric else None
            beats = bool(bp and bb and bp[1][0] < bb[1][0])
            matches = bool(bp and pp and bp[1][0] <= pp[1])
        ok = not missing and beats and matches
        verdicts.append((bool(missing), ok))
        done = "yes" if not missing else f"no ({len(missing)} models short)"
        beat_cell = "— (no baseline yet)" if bb is None else ("yes" if beats else "**no**")
        lines.append(f"| {_benchmark(env)} | {done} | {beat_cell} | {'yes' if matches else '**no**'} | "
                     f"{'**yes**' if ok else 'no'} |")
    passed = sum(ok for _, ok in verdicts)
    short = sum(m for m, _ in verdicts)
    lines += ["", f"{passed} of {len(envs)} rows pass; {short} incomplete."]
    return lines


def write_reports(records: Sequence[Mapping[str, Any]], out_dir: str | Path, title: str = "phast-bench results",
                  note: str = "") -> dict[str, Path]:
    """Write ``summary.csv`` and ``tables.md`` into ``out_dir``; return their paths."""
    out_dir = Path(out_dir)
    agg = aggregate(records)
    csv_path = write_summary_csv(agg, out_dir / "summary.csv")
    md_path = out_dir / "tables.md"
    atomic_write_text(md_path, markdown_tables(agg, title, note))
    return {"summary_csv": csv_path, "tables_md": md_path}
