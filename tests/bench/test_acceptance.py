"""phast_model.bench.acceptance (benchmarks/phast_windy.py --check): other machines' references (no training: the run
is faked)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from phast_model.bench import acceptance

ENV = "PHAST/WindyPendulum-v0"
HERE = {"cpu": "cpu B", "torch_cpu_capability": "AVX512", "torch": "2.13.0+cpu", "numpy": "2.4.6", "scipy": "1.17.1"}


@pytest.fixture()
def pw(monkeypatch: pytest.MonkeyPatch):  # noqa: ANN201
    monkeypatch.setattr(acceptance, "numerics", lambda: dict(HERE))
    fresh = {"damping_r2": 0.851, "rollout_theta_wrap_mse_h100": 0.0019, "theta_wrap_mse": 2.15e-4}
    monkeypatch.setattr(acceptance, "train_one", lambda env, regime, seed, *a: {"env_id": env, "regime": regime, "seed": seed, **fresh})
    return acceptance


def _run(commit: str, r2: float, roll: float, numerics: dict | None = None) -> dict:
    return {"env_id": ENV, "regime": "partial", "seed": 0, "commit": commit, "damping_r2": r2,
            "rollout_theta_wrap_mse_h100": roll, "theta_wrap_mse": 2.15e-4, **({"numerics": numerics} if numerics else {})}


def test_check_uses_this_machines_reference(pw, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "pw.json"
    out.write_text(json.dumps({"runs": [_run("b400815", 0.883, 0.00167)]}))
    todo = [(ENV, "partial")]
    assert pw.check(out, todo, [0], 1, 10) == 1  # machine A's number, run on machine B: drift
    assert "DRIFT" in capsys.readouterr().out
    other = tmp_path / "old.json"  # the committed code, run on machine B
    other.write_text(json.dumps({"runs": [_run("0e2d87e", 0.851, 0.0019, HERE)]}))
    refs = pw.import_references(out, other)
    assert [r["commit"] for r in refs] == ["0e2d87e"] and json.loads(out.read_text())["runs"][0]["damping_r2"] == 0.883
    assert pw.check(out, todo, [0], 1, 10) == 0
    assert "this machine's reference 0.851 (at 0e2d87e)" in capsys.readouterr().out
    pw.import_references(out, other)  # importing again replaces, does not duplicate
    assert len(json.loads(out.read_text())[pw.MACHINE_REFS]) == 1
    elsewhere = {**HERE, "cpu": "cpu C"}  # a third machine still compares with the committed run
    assert pw.reference_for(json.loads(out.read_text()), ENV, "partial", 0, elsewhere) is None


def test_import_refuses_runs_without_a_committed_run_or_fingerprint(pw, tmp_path: Path) -> None:
    out = tmp_path / "pw.json"
    out.write_text(json.dumps({"runs": [_run("b400815", 0.883, 0.00167)]}))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"runs": [_run("0e2d87e", 0.851, 0.0019)]}))  # no numerics
    with pytest.raises(SystemExit, match="numerics"):
        pw.import_references(out, bad)
    bad.write_text(json.dumps({"runs": [{**_run("0e2d87e", 0.851, 0.0019, HERE), "seed": 7}]}))
    with pytest.raises(SystemExit, match="no committed run"):
        pw.import_references(out, bad)


def test_summary_skips_undefined_values(pw) -> None:
    """A constant true D records damping R^2 as None (NaN in memory): the summary and the table leave it out."""
    runs = [{"env_id": "PHAST/DampedPendulum-v0", "regime": "known", "seed": s, "damping_r2": v, "damping_mae": 0.006,
             "rollout_theta_wrap_mse_h100": 6e-4, "train_wall_time_s": 70.0, "n_parameters": 1285}
            for s, v in enumerate([None, float("nan")])]
    s = pw.summarize_acceptance(runs)["PHAST/DampedPendulum-v0|known"]
    assert "damping_r2" not in s and s["damping_mae"]["values"] == [0.006, 0.006]
    assert "| DampedPendulum-v0 | known | 2 |" in pw.markdown_table({"runs": runs})
