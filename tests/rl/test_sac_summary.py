"""benchmarks.sac.summary (benchmarks/control_sac_summary.py): rows of several seeds pooled by setting and method."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.sac.summary import load_rows, summarize
from tests import ROOT


def _row(method: str, seed: int, angle: float, samples: int, secs: float) -> dict:
    return {"method": method, "seed": seed, "success_rate": 0.0, "success_angle_rate": angle, "final_error": 0.02,
            "effort": 1234.4, "u_rms_final": 0.87, "real_env_samples": samples, "train_seconds": secs}


def _write(d: Path, rows: list[dict], regimes: list[str] | None = None, plant: str = "PHAST/DampedPendulum-v0") -> Path:
    d.mkdir()
    meta = {"q_star": 3.141592653589793, "protocol": {"env_id": plant}, "results": rows}
    if regimes:
        meta["regimes"] = regimes
    (d / "control_sac.json").write_text(json.dumps(meta))
    return d


def test_seeds_pool_by_setting_and_method(tmp_path: Path) -> None:
    dirs = [_write(tmp_path / f"s{s}", [_row("energy-casimir/oracle", 0, 1.0, 0, 0.0), _row("sac-world/x", s, a, 4000 + s, 100.0 * s)])
            for s, a in ((0, 1.0), (1, 0.9), (2, 0.8))]
    old = _row("sac-world/x", 0, 1.0, 4300, 50.0)
    del old["seed"]
    old["command"] = "python benchmarks/control_sac.py --seed 7"  # older rows: the seed only in the command
    dirs.append(_write(tmp_path / "old", [old], ["far_stable"]))
    dirs.append(_write(tmp_path / "swing", [_row("sac-world/x", 0, 1.0, 4300, 50.0)], ["near_stable"], "PHAST/Pendulum-v0"))
    text = summarize(load_rows(dirs), 0.087)
    lines = text.splitlines()
    assert len(lines) == 2 + 4  # header, rule, EC + SAC of the upright, the older row, SAC of the swing-up
    sac = next(line for line in lines if "sac-world/x" in line and "all regimes" in line)
    assert "| 0,1,2 |" in sac and "0.90 (1.00, 0.90, 0.80)" in sac and "4,001" in sac and "| 200 |" in sac
    assert "10.0x" in sac and "| 1,234 |" in sac  # 0.87 / 0.087; effort
    assert any("Pendulum-v0, upright, from near_stable" in line for line in lines)
    assert any("from far_stable | sac-world/x | 7 |" in line for line in lines)
    with pytest.raises(ValueError, match="not a control_sac.py result"):
        load_rows([tmp_path / "missing"])
    # the script prints the same table, and exits 2 naming a folder without results
    script = [sys.executable, str(ROOT / "benchmarks" / "control_sac_summary.py")]
    done = subprocess.run([*script, *map(str, dirs), "--floor", "0.087"], capture_output=True, text=True, check=True)
    assert done.stdout == text
    bad = subprocess.run([*script, str(tmp_path / "missing")], capture_output=True, text=True)
    assert bad.returncode == 2 and "missing" in bad.stderr
