"""One table over training seeds: the rows of several ``control_sac.py`` output folders, grouped by method and setting.

Each SAC row of ``DIR/control_sac.json`` is one training seed; rows of the same method, plant, target and start
regimes are pooled (success rates and errors averaged over seeds, per-seed angle-only successes listed, real
samples and wall time as mean and max).  Energy-Casimir rows are deterministic per evaluation seed and are
averaged the same way.  ``--floor`` (N m) adds the RMS torque as a multiple of a torque floor (the LQG bound of
docs/control.md for sigma = 0.01: 0.087 N m).

``benchmarks/control_sac_summary.py`` prints it.
"""

from __future__ import annotations

import json
import math
import re
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.control import START_REGIMES, ControlProtocol


@dataclass(frozen=True)
class Setting:
    """What a row was measured on: plant, target, start regimes."""

    plant: str
    q_star: float
    regimes: tuple[str, ...]

    def label(self) -> str:
        target = "upright" if abs(math.cos(self.q_star) + 1) < 1e-9 else f"q* = {self.q_star:g}"
        where = "all regimes" if set(self.regimes) == set(START_REGIMES) else "from " + ", ".join(self.regimes)
        return f"{self.plant.split('/')[-1]}, {target}, {where}"


def load_rows(dirs: Sequence[str | Path]) -> list[tuple[Setting, dict[str, Any]]]:
    """(setting, row) of every row in the folders; ValueError naming a folder without a readable control_sac.json."""
    out = []
    for d in dirs:
        path = Path(d) / "control_sac.json"
        try:
            meta = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}: not a control_sac.py result ({e})") from None
        setting = Setting(meta.get("protocol", {}).get("env_id", ControlProtocol.env_id), float(meta["q_star"]),
                          tuple(meta.get("regimes", START_REGIMES)))
        out += [(setting, r) for r in meta["results"]]
    return out


def _seed(row: dict[str, Any]) -> int:
    """A row's training seed (older rows record it only in their command line; default 0)."""
    if "seed" in row:
        return int(row["seed"])
    m = re.search(r"--seed (\d+)", row.get("command", ""))
    return int(m.group(1)) if m else 0


def summarize(rows: Sequence[tuple[Setting, dict[str, Any]]], floor: float | None = None) -> str:
    """The markdown table of :func:`load_rows`' rows pooled by (setting, method)."""
    groups: dict[tuple[Setting, str], list[dict[str, Any]]] = defaultdict(list)
    for setting, r in rows:
        groups[(setting, r["method"])].append(r)
    head = ["Setting", "Method", "Seeds", "Success", "Angle only (per seed)", "Final error (rad)", "Effort",
            "RMS torque (N m)"]
    head += (["RMS / floor"] if floor else []) + ["Real samples (mean)", "Train s (max)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for (setting, method), rs in sorted(groups.items(), key=lambda kv: (kv[0][0].label(), not kv[0][1].startswith("energy"), kv[0][1])):
        sac = not method.startswith("energy")
        rs = sorted(rs, key=_seed)
        seeds = [_seed(r) for r in rs] if sac else ["-"]
        angle = [r["success_angle_rate"] for r in rs]
        rms = float(np.mean([r["u_rms_final"] for r in rs]))
        cells = [setting.label(), method, ",".join(map(str, seeds)), f"{np.mean([r['success_rate'] for r in rs]):.2f}",
                 f"{np.mean(angle):.2f}" + (f" ({', '.join(f'{a:.2f}' for a in angle)})" if sac else ""),
                 f"{np.mean([r['final_error'] for r in rs]):.3g}", f"{np.mean([r['effort'] for r in rs]):,.0f}", f"{rms:.3g}"]
        cells += [f"{rms / floor:.1f}x"] if floor else []
        cells += [f"{np.mean([r['real_env_samples'] for r in rs]):,.0f}", f"{max(r['train_seconds'] for r in rs):.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
