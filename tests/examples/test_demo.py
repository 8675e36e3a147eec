"""examples/demo.py, the runner of ``make demo``, run as a script beside stand-in stages (fast)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

from tests import ROOT

WORLD_MODEL_STAGE = textwrap.dedent('''
    def run(out_dir):
        return {"env": "PHAST/WindyPendulum-v0", "regime": "partial", "rollout_theta_wrap_mse_h100": 0.01,
                "theta_wrap_mse": 0.000197, "damping_r2": 0.5, "train_wall_time_s": 17.1,
                "figure": str(out_dir / "rollout.png")}
''')


def test_demo_runner_skips_a_missing_stage_and_tabulates_the_stages(tmp_path: Path) -> None:
    """A missing stage is skipped, a failing one reported while the others run, the headline numbers tabulated with
    the pictures' paths relative to the output folder, and the exit status says that a stage failed."""
    here = tmp_path / "examples"  # the runner imports its stages from beside itself: a copy beside stand-ins
    here.mkdir()
    shutil.copy(ROOT / "examples" / "demo.py", here / "demo.py")
    (here / "demo_world_model.py").write_text(WORLD_MODEL_STAGE)
    (here / "demo_control.py").write_text("def run(out_dir):\n    raise RuntimeError('boom')\n")
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, str(here / "demo.py"), "--out", str(out), "--stages",
                           "world_model,control,mismatch"], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 1, done.stderr
    stages = json.loads((out / "summary.json").read_text())["stages"]
    assert [stages[s]["status"] for s in ("world_model", "control", "mismatch")] == ["ok", "failed", "skipped"]
    assert "demo_mismatch.py" in stages["mismatch"]["reason"]
    table = done.stdout[done.stdout.index("[demo] summary"):].splitlines()
    assert table[1].split()[:3] == ["stage", "time", "what"]
    text = "\n".join(table)
    assert "0.01" in text and "world_model/rollout.png" in text and str(out / "world_model") not in text
    assert "RuntimeError: boom" in text and "skipped" in text
    assert max(len(line) for line in table) < 200  # a table, not JSON lines
