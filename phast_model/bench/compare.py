"""Compare the per-run results of two ``phast-bench`` output directories, run by run, bit for bit
(``benchmarks/compare_runs.py OUT_A OUT_B``).

Runs are matched by their result path ``runs/<env>/<model>/seed<k>-<confighash>.json`` (the hash is of the full
configuration, so a match is the same run).  Compared per run: ``metrics``, ``best_val``, ``params`` and the
training ``history`` without its wall times (``time_s``); provenance (host, wall times, finish time, commit) is
not compared.  Used to show that ``--backend ray`` gives the same numbers as ``--backend local`` (docs/ray.md).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: record fields compared (the run's numbers); everything else is provenance
COMPARED_FIELDS = ("metrics", "best_val", "params", "history")
#: keys dropped inside the history (wall-clock times differ run to run)
VOLATILE_KEYS = frozenset({"time_s"})


@dataclass(frozen=True)
class RunComparison:
    """One run's verdict: ``status`` is ``identical``, ``differs``, ``only in A`` or ``only in B``."""

    run: str
    status: str
    n_values: int = 0
    max_abs_diff: float = 0.0
    first_diff: str = ""


def _load_runs(out_dir: Path) -> dict[str, dict[str, Any]]:
    runs = out_dir / "runs"
    if not runs.is_dir():
        raise ValueError(f"{out_dir} has no runs/ directory: not a phast-bench output directory")
    out: dict[str, dict[str, Any]] = {}
    for path in sorted(runs.rglob("*.json")):
        try:
            out[path.relative_to(runs).as_posix()] = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"unreadable result file {path}: {exc}") from None
    return out


def _flatten(x: object, prefix: str = "") -> dict[str, Any]:
    """Nested dicts / lists -> {"a.b[0].c": leaf}, dropping :data:`VOLATILE_KEYS`."""
    if isinstance(x, dict):
        out: dict[str, Any] = {}
        for k in sorted(x):
            if k not in VOLATILE_KEYS:
                out.update(_flatten(x[k], f"{prefix}.{k}" if prefix else str(k)))
        return out
    if isinstance(x, list):
        out = {}
        for i, v in enumerate(x):
            out.update(_flatten(v, f"{prefix}[{i}]"))
        return out
    return {prefix: x}


def compare_records(a: Mapping[str, object], b: Mapping[str, object]) -> tuple[bool, int, float, str]:
    """(identical, number of values compared, largest |a - b| over numbers, first differing field) of two records."""
    fa = _flatten({k: a.get(k) for k in COMPARED_FIELDS})
    fb = _flatten({k: b.get(k) for k in COMPARED_FIELDS})
    max_diff, first = 0.0, ""
    for key in sorted(fa.keys() | fb.keys()):
        va, vb = fa.get(key, "<missing>"), fb.get(key, "<missing>")
        if va == vb and type(va) is type(vb):
            continue
        first = first or key
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (va, vb))
        diff = abs(va - vb) if numeric else math.inf
        max_diff = max(max_diff, diff if not math.isnan(diff) else math.inf)
    return not first, len(fa.keys() | fb.keys()), max_diff, first


def compare_dirs(dir_a: str | Path, dir_b: str | Path) -> list[RunComparison]:
    """Compare every run of two ``phast-bench`` output directories (ValueError if one is not one)."""
    runs_a, runs_b = _load_runs(Path(dir_a)), _load_runs(Path(dir_b))
    if not runs_a and not runs_b:
        raise ValueError(f"no run results under {dir_a}/runs or {dir_b}/runs")
    rows = []
    for run in sorted(runs_a.keys() | runs_b.keys()):
        if run not in runs_b:
            rows.append(RunComparison(run, "only in A"))
        elif run not in runs_a:
            rows.append(RunComparison(run, "only in B"))
        else:
            same, n, diff, first = compare_records(runs_a[run], runs_b[run])
            rows.append(RunComparison(run, "identical" if same else "differs", n, diff, first))
    return rows


def format_table(rows: list[RunComparison]) -> str:
    """Markdown table of the comparison and a one-line verdict."""
    lines = ["| run | values compared | verdict | max abs diff | first differing field |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r.run} | {r.n_values} | {r.status} | {r.max_abs_diff:.3g} | {r.first_diff or '-'} |")
    n_same = sum(r.status == "identical" for r in rows)
    lines.append(f"\n{n_same}/{len(rows)} runs bit-identical")
    return "\n".join(lines)
