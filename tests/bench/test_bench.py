"""Benchmark harness: config hashing, resume, outputs, CLI, executors (tiny budgets: seconds)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from phast_model.bench import (
    PAPER,
    TABLE4_ENVS,
    LocalExecutor,
    RunSpec,
    aggregate,
    grid,
    load_result,
    make_executor,
    parse_seeds,
    result_path,
    run_key,
    run_sweep,
    write_reports,
)
from phast_model.bench.runner import safe_run_one
from phast_model.cli.bench import main
from tests import ROOT

ENV = "PHAST/WindyPendulum-v0"
TINY = dict(epochs=1, n_train=6, n_val=3, n_test=3, T=30, horizons=(5, 10), burn_in=5, train={"batch_size": 4})


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PHAST_CACHE_DIR", str(tmp_path / "cache"))


def test_run_key_is_stable_and_sensitive() -> None:
    spec = RunSpec(ENV, "gru", seed=3, train={"lr": 1e-3, "batch_size": 64})
    same = RunSpec(ENV, "gru", seed=3, train={"batch_size": 64, "lr": 1e-3})  # dict order irrelevant
    assert run_key(spec) == run_key(same) == run_key(RunSpec.from_config(spec.config()))
    # the same key in a fresh interpreter (no hash randomization effects)
    code = (f"from phast_model.bench import RunSpec, run_key; "
            f"print(run_key(RunSpec('{ENV}', 'gru', seed=3, train={{'lr': 1e-3, 'batch_size': 64}})))")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == run_key(spec)
    for change in ({"seed": 4}, {"epochs": 49}, {"model": "lstm"}, {"n_train": 999}, {"data_seed": 1}, {"horizons": (10,)},
                   {"train": {"lr": 2e-3, "batch_size": 64}}, {"model_kw": {"d_model": 128}}, {"full_state": True}):
        assert run_key(RunSpec(**{**spec.config(), "horizons": tuple(spec.horizons), **change})) != run_key(spec)


def test_model_revision_changes_only_that_models_key() -> None:
    """A model revision re-keys that model's runs (stale results are redone); other models keep their keys."""
    from phast_model.bench import spec as spec_mod

    gru, tf = RunSpec(ENV, "gru", seed=3), RunSpec(ENV, "transformer", seed=3)
    assert "model_revision" not in gru.config()
    assert tf.config()["model_revision"] == spec_mod.MODEL_REVISIONS["transformer"]
    assert run_key(RunSpec.from_config(tf.config())) == run_key(tf)
    keys = run_key(gru), run_key(tf)
    old = dict(spec_mod.MODEL_REVISIONS)
    try:
        spec_mod.MODEL_REVISIONS["transformer"] += 1
        assert run_key(gru) == keys[0] and run_key(tf) != keys[1]
    finally:
        spec_mod.MODEL_REVISIONS.clear()
        spec_mod.MODEL_REVISIONS.update(old)


def test_env_model_revision_rekeys_that_env_only() -> None:
    """A revision of one (model, env) pair re-keys that env's runs of the model and no other."""
    from phast_model.bench import spec as spec_mod

    pp, pend = RunSpec("PHAST/PredatorPrey-v0", "phast-partial"), RunSpec("PHAST/Pendulum-v0", "phast-partial")
    assert pp.config()["model_revision"] == spec_mod.ENV_MODEL_REVISIONS[("phast-partial", "PHAST/PredatorPrey-v0")]
    assert pend.config()["model_revision"] == spec_mod.MODEL_REVISIONS["phast-partial"]
    keys = run_key(pp), run_key(pend)
    old = dict(spec_mod.ENV_MODEL_REVISIONS)
    try:
        spec_mod.ENV_MODEL_REVISIONS[("phast-partial", "PHAST/PredatorPrey-v0")] += 1
        assert run_key(pp) != keys[0] and run_key(pend) == keys[1]
    finally:
        spec_mod.ENV_MODEL_REVISIONS.clear()
        spec_mod.ENV_MODEL_REVISIONS.update(old)


def test_spec_validation_and_seed_parsing() -> None:
    with pytest.raises(ValueError, match="unknown model"):
        RunSpec(ENV, "mamba")
    with pytest.raises(ValueError, match="epochs"):
        RunSpec(ENV, "gru", epochs=0)
    assert parse_seeds("0-4") == [0, 1, 2, 3, 4]
    assert parse_seeds("0-1,5") == [0, 1, 5]
    with pytest.raises(ValueError, match="seed list"):
        parse_seeds("4-1")
    specs = grid([ENV], ["gru", "dhnn"], [0, 1])
    assert len(specs) == 4 and all(s.full_state == (s.model == "dhnn") for s in specs)


def test_paper_table_matches_table4() -> None:
    """Best paper PHAST / best baseline per row reproduce paper Table 4 (spot checks)."""
    assert len(TABLE4_ENVS) == 13
    windy = PAPER[ENV]
    assert windy.best("phast-")[:2] == ("phast-partial", 0.092)
    assert windy.best("!phast-")[:2] == ("dlinoss", 0.435)
    assert PAPER["PHAST/WindyCartPole-v0"].best("!phast-")[:2] == ("s5", 0.431)
    assert PAPER["PHAST/HeatExchange-v0"].best("!phast-")[:2] == ("linoss", 4.46e-4)
    assert PAPER["PHAST/PredatorPrey-v0"].best("phast-")[:2] == ("phast-unknown", 0.0199)


def test_tiny_sweep_resume_and_outputs(tmp_path: Path) -> None:
    out = tmp_path / "res"
    specs = grid([ENV], ["phast-known", "gru"], [0], **TINY)
    recs = run_sweep(specs, out, workers=1, progress=False)
    assert sorted(r["status"] for r in recs) == ["ran", "ran"], [r.get("error") for r in recs]
    for spec in specs:
        rec = json.loads(result_path(out, spec).read_text())
        assert rec["key"] == run_key(spec) and rec["env"] == ENV and rec["seed"] == 0
        assert rec["params"] > 0 and rec["wall_time_s"] > 0 and rec["config"]["epochs"] == 1
        assert "rollout_theta_wrap_mse_h10" in rec["metrics"] and "mse" in rec["metrics"]
    mtimes = {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.json")}
    # second call: nothing is redone
    again = run_sweep(specs, out, workers=1, progress=False)
    assert [r["status"] for r in again] == ["cached", "cached"]
    assert {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.json")} == mtimes
    # an interrupted sweep (one result missing) and a corrupted file rerun only those runs
    result_path(out, specs[0]).unlink()
    result_path(out, specs[1]).write_text("{truncated")
    assert load_result(out, specs[1]) is None
    assert sorted(r["status"] for r in run_sweep(specs, out, workers=1, progress=False)) == ["ran", "ran"]

    paths = write_reports(run_sweep(specs, out, workers=1, progress=False), out)
    rows = list(csv.DictReader(paths["summary_csv"].open()))
    assert {r["model"] for r in rows} == {"phast-known", "gru"}
    assert set(rows[0]) == {"env", "model", "metric", "mean", "std", "n_seeds", "params"}
    md = paths["tables_md"].read_text()
    assert "Pendulum (windy)" in md and "PHAST (KNOWN)" in md and "GRU" in md and "rollout_theta_wrap_mse_h10" in md

    from phast_model.bench.figures import make_figures

    figs = make_figures(out, specs, n_traj=1, H=10)
    assert sorted(p.name for p in figs) == ["WindyPendulum-v0_damping_energy.png", "WindyPendulum-v0_rollout.png"]
    assert all(p.stat().st_size > 1000 for p in figs)

    # a run whose saved weights are gone (a machine reset) is drawn from its next seed
    from phast_model.bench.figures import _pick, _rollouts
    from phast_model.bench.runner import BENCH_MODEL_FILE, work_dir

    gru1 = grid([ENV], ["gru"], [1], **TINY)
    run_sweep(gru1, out, workers=1, progress=False)
    gru0 = next(s for s in specs if s.model == "gru")
    runs = _pick([load_result(out, s) for s in [*specs, *gru1]], ENV, False)
    assert [(r["model"], r["seed"]) for r in runs] == [("gru", 0), ("gru", 1)]
    (work_dir(out, gru0) / BENCH_MODEL_FILE).unlink()
    assert set(_rollouts(out, ENV, [runs], n_traj=1, H=10).preds) == {"gru"}
    (work_dir(out, gru1[0]) / BENCH_MODEL_FILE).unlink()
    with pytest.warns(UserWarning, match="no saved weights load"):
        assert _rollouts(out, ENV, [runs], n_traj=1, H=10) is None


def test_cli(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = str(tmp_path / "cli")
    base = ["--envs", "WindyPendulum-v0", "--models", "gru", "--seeds", "0", "--epochs", "1", "--n-train", "6",
            "--n-val", "3", "--n-test", "3", "--T", "30", "--horizons", "5", "--burn-in", "5", "--train", "batch_size=4",
            "--out", out, "--workers", "1", "--no-progress"]
    assert main(base + ["--dry-run"]) == 0
    assert "1 runs: 0 done, 1 pending" in capsys.readouterr().out
    assert main(base) == 0
    assert json.loads(capsys.readouterr().out)["ran"] == 1
    assert main(base) == 0
    assert json.loads(capsys.readouterr().out)["cached"] == 1
    assert main(base + ["--summarize-only"]) == 0
    assert (Path(out) / "summary.csv").exists()
    assert main(["--models", "mamba", "--out", out]) == 2
    assert main(["--envs", "NoSuchEnv-v0", "--out", out]) == 2
    assert main(base[:-5] + ["--train", "no_such_field=1", "--out", out, "--workers", "1", "--no-progress"]) == 1
    assert "unknown TrainConfig field" in capsys.readouterr().out


def test_executors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown backend"):
        make_executor("slurm")
    ex = LocalExecutor(workers=2)
    bad = [{"env_id": ENV, "model": "nope", "seed": i} for i in range(2)]  # fails fast inside the workers
    try:
        recs = list(ex.map_unordered(safe_run_one, bad, str(tmp_path)))
    finally:
        ex.shutdown()
    assert len(recs) == 2 and all(r["status"] == "failed" and "unknown model" in r["error"] for r in recs)


@pytest.mark.ray
def test_ray_two_run_sweep(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    specs = grid([ENV], ["gru"], [0, 1], **TINY)
    recs = run_sweep(specs, tmp_path / "ray", backend="ray", workers=2, progress=False)
    assert sorted(r["status"] for r in recs) == ["ran", "ran"], [r.get("error") for r in recs]
    assert [r["status"] for r in run_sweep(specs, tmp_path / "ray", backend="ray", workers=2, progress=False)] == ["cached"] * 2


def test_first_step_floor_is_below_persistence() -> None:
    """The t = 0 floor E Var(q1 | q0) / (T - 1) is positive and below the persistence predictor's t = 0 term."""
    from phast_gym.datasets import make_splits
    from phast_model.bench.floor import first_step_floor

    r = first_step_floor("PHAST/NBody3-v0", n_train=4, n_val=2, n_test=8, T=20, draws=64)
    test = make_splits("PHAST/NBody3-v0", 4, 2, 8, T=20, seed=42)["test"]
    persistence = float(((test.q[:, 1] - test.q[:, 0]) ** 2).mean()) / 19
    assert 0.0 < r["floor_mse"] < 2.0 * persistence
    # the best first prediction scored on the test split's own q_1: the same floor up to the test sample's noise
    assert 0.3 < r["test_floor_mse"] / r["floor_mse"] < 3.0
    with pytest.raises(ValueError, match="draws"):
        first_step_floor("PHAST/NBody3-v0", n_train=4, n_val=2, n_test=8, T=20, draws=1)


def test_env_energy_rejects_non_hamiltonian_env() -> None:
    """Figures: predator-prey has no mechanical energy; env_energy says so (the figure code catches ValueError)."""
    import numpy as np

    from phast_model.train.metrics import env_energy

    q = np.ones((1, 5, 1))
    with pytest.raises(ValueError, match="not port-Hamiltonian"):
        env_energy("PHAST/PredatorPrey-v0", q, 0.1, ())
    assert env_energy("PHAST/RLCCircuit-v0", q, 0.1, ()).shape == (1, 4)


def _alive(pid: int) -> bool:
    """A process that still runs (a zombie waiting to be reaped counts as gone)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            return not any(line.startswith("State:") and "Z" in line.split()[1] for line in fh)
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_killed_sweep_leaves_no_live_workers(tmp_path: Path) -> None:
    """SIGKILL of ``phast-bench --workers 2`` mid-training: its workers die with it (no orphan keeps training and
    writing checkpoints), and the run directories are not left locked for a rerun."""
    import os
    import signal
    import time

    from phast_gym.fileio import dir_lock

    out = tmp_path / "sweep"
    root = str(ROOT)
    env = {**os.environ, "PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", ""), "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "phast_model.cli.bench", "--envs", "Pendulum-v0", "--models", "gru", "--seeds", "0-1",
           "--epochs", "100000", "--n-train", "4", "--n-val", "2", "--n-test", "2", "--T", "20", "--horizons", "5",
           "--burn-in", "5", "--train", "batch_size=4", "--out", str(out), "--workers", "2", "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pids: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while len(pids) < 2:  # both workers hold their run's lock (the lock file names the holder) and train
            assert proc.poll() is None and time.monotonic() < deadline, "the workers never started training"
            time.sleep(0.2)
            locks = [p / ".lock" for p in (out / "work").glob("*/*/*") if (p / "checkpoint.pt").exists()]
            pids = [int(t) for lk in locks if (t := lk.read_text().strip()).isdigit()]
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert proc.pid not in pids and all(pid != os.getpid() for pid in pids)
    deadline = time.monotonic() + 30
    while any(_alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in pids), "workers outlived the killed sweep"
    for wdir in (out / "work").glob("*/*/*"):
        # free again: a rerun can take it (the kernel may drop a dead holder's flock a moment after the process
        # shows as a zombie: its last file close can be deferred to a kernel worker, seen once under load)
        with dir_lock(wdir, wait_s=5.0):
            pass


def test_run_directory_lock_is_exclusive(tmp_path: Path) -> None:
    from phast_gym.fileio import DirLocked, dir_lock

    with dir_lock(tmp_path):
        code = f"from phast_gym.fileio import dir_lock\nwith dir_lock({str(tmp_path)!r}): pass"
        res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
        assert res.returncode != 0 and "in use by another process" in res.stderr
    with pytest.raises(DirLocked):
        with dir_lock(tmp_path):
            with dir_lock(tmp_path):
                pass


@pytest.mark.parametrize("bad, msg", [(["--workers", "0"], "--workers"), (["--workers", "-4"], "--workers"),
                                      (["--models", ""], "--models is empty"), (["--envs", " , "], "--envs is empty"),
                                      (["--seeds", "0-100000000", "--dry-run"], "more than 10000 seeds"),
                                      (["--seeds", "0-999", "--dry-run"], "more than 20000")])
def test_cli_rejects_bad_grid_at_once(tmp_path: Path, capsys: pytest.CaptureFixture, bad: list[str], msg: str) -> None:
    import time

    t0 = time.perf_counter()
    assert main(["--out", str(tmp_path / "o"), *bad]) == 2
    assert msg in capsys.readouterr().err
    assert time.perf_counter() - t0 < 5 and not (tmp_path / "o").exists()


def test_cli_refuses_unwritable_out_before_any_run(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    (tmp_path / "file").write_text("x")
    assert main(["--envs", "Pendulum-v0", "--models", "gru", "--seeds", "0", "--out", str(tmp_path / "file"),
                 "--workers", "1", "--no-progress"]) == 2
    assert "not a directory" in capsys.readouterr().err


def test_regime_table_puts_each_regime_next_to_the_papers():
    from phast_model.bench.paper import PAPER
    from phast_model.bench.summary import regime_table

    env = "PHAST/WindyPendulum-v0"
    paper = PAPER[env].results["phast-partial"][0]
    agg = {(env, "phast-partial"): {"metrics": {"rollout_theta_wrap_mse_h100": (paper / 2, 0.0, 5)}}}
    lines = regime_table(agg, [env])
    row = next(ln for ln in lines if ln.startswith(f"| {PAPER[env].benchmark} |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1] == "`rollout_theta_wrap_mse_h100`"
    assert cells[7] == "0.5"  # PARTIAL: ours, paper, ours / paper
    assert cells[5] != "—" and cells[6] != "—"
    assert cells[2] == "—" and cells[4] == "—"  # KNOWN not run: no number, no ratio


def test_floor_rule_judges_nbody_against_its_information_floor():
    from phast_model.bench.floor import first_step_floor
    from phast_model.bench.summary import floor_rule

    env = "PHAST/NBody3-v0"
    floor = first_step_floor(env)["floor_mse"]

    def agg_with(phast90: float) -> dict:
        return {(env, "phast-partial"): {"metrics": {"mse": (phast90, 0.0, 5), "mse_after_burnin": (1e-9, 0.0, 5)}},
                (env, "gru"): {"metrics": {"mse": (10 * floor, 0.0, 5), "mse_after_burnin": (1e-6, 0.0, 5)}}}

    row = floor_rule(agg_with(1.05 * floor), [env])[-1]
    assert row.endswith("| yes | yes | **yes** |")
    row = floor_rule(agg_with(1.5 * floor), [env])[-1]  # above 1.1 x the floor
    assert row.endswith("| no | yes | no |")
    assert floor_rule(agg_with(floor), ["PHAST/Pendulum-v0"]) == []


def test_phast_run_seed_seeds_the_model_weights() -> None:
    # the run's seed is the PHAST model's seed, as with phast-train --seed: seeds differ in their initial weights,
    # an explicit model_kw seed wins, and the weights of a seed match build_model(..., seed=seed)
    from phast_model.bench.runner import build_run_model
    from phast_model.world.regimes import build_model

    def weights(model) -> list:  # noqa: ANN001
        return [t.detach().clone() for t in model.state_dict().values()]

    def same(a: list, b: list) -> bool:
        return all(x.shape == y.shape and bool((x == y).all()) for x, y in zip(a, b, strict=True))

    w0 = weights(build_run_model(RunSpec(ENV, "phast-unknown", seed=0), None))
    w1 = weights(build_run_model(RunSpec(ENV, "phast-unknown", seed=1), None))
    assert not same(w0, w1)
    assert same(w1, weights(build_model(ENV, "unknown", seed=1)))
    assert same(w0, weights(build_run_model(RunSpec(ENV, "phast-unknown", seed=1, model_kw={"seed": 0}), None)))


def test_summary_leaves_out_damping_r2_where_true_d_is_constant() -> None:
    """Old records hold R^2 ~ -1e12 for a constant true D (round-off denominator); the mean leaves them out."""
    def rec(env: str, seed: int, r2: float) -> dict:
        return {"env": env, "model": "phast-known", "seed": seed, "params": 1,
                "metrics": {"damping_r2": r2, "damping_mae": 0.01, "mse": 1e-6}}

    agg = aggregate([rec("PHAST/DampedPendulum-v0", 0, -1.4e12), rec("PHAST/DampedPendulum-v0", 1, -1.3e12),
                     rec("PHAST/WindyPendulum-v0", 0, 0.99), rec("PHAST/WindyPendulum-v0", 1, 0.98),
                     rec("PHAST/NotInThisCheckout-v0", 0, 0.5)])
    damped = agg[("PHAST/DampedPendulum-v0", "phast-known")]["metrics"]
    assert "damping_r2" not in damped and damped["damping_mae"][2] == 2
    windy = agg[("PHAST/WindyPendulum-v0", "phast-known")]["metrics"]["damping_r2"]
    assert windy[0] == pytest.approx(0.985) and windy[2] == 2
    assert agg[("PHAST/NotInThisCheckout-v0", "phast-known")]["metrics"]["damping_r2"][0] == 0.5


def test_code_commit_names_the_imported_checkout() -> None:
    """Run records name the commit of the phast_model they ran (one helper for the harness and the scripts)."""
    import re

    from phast_model.bench.runner import _CODE_COMMIT
    from phast_model.train.provenance import code_commit

    full, short = code_commit(), code_commit(short=True, dirty=True)
    if full is None:  # not a git checkout (an installed wheel): nothing to name
        pytest.skip("phast_model is not in a git checkout")
    assert re.fullmatch(r"[0-9a-f]{40}", full) and re.fullmatch(r"[0-9a-f]{40}", _CODE_COMMIT)
    assert re.fullmatch(r"[0-9a-f]{4,40}(\+dirty)?", short) and full.startswith(short.split("+")[0])


def test_acceptance_table_needs_a_complete_row_that_beats_baselines_and_the_paper():
    from phast_model.bench.paper import PAPER
    from phast_model.bench.spec import ALL_MODELS
    from phast_model.bench.summary import acceptance_table

    env = "PHAST/WindyPendulum-v0"
    metric, paper = PAPER[env].metric, PAPER[env].best("phast-")[1]

    def agg_with(phast: float, base: float, models: tuple[str, ...] = ALL_MODELS) -> dict:
        return {(env, m): {"metrics": {metric: (phast if m.startswith("phast-") else base, 0.0, 5)},
                           "seeds": [0, 1, 2, 3, 4]} for m in models}

    def row(agg: dict) -> list[str]:
        lines = acceptance_table(agg, [env])
        return [c.strip() for c in lines[-3].strip("|").split("|")] + [lines[-1]]

    assert row(agg_with(paper / 2, paper)) == [PAPER[env].benchmark, "yes", "yes", "yes", "**yes**",
                                               "1 of 1 rows pass; 0 incomplete."]
    assert row(agg_with(paper / 2, paper / 4))[2:5] == ["**no**", "yes", "no"]  # a baseline wins
    assert row(agg_with(2 * paper, 4 * paper))[2:5] == ["yes", "**no**", "no"]  # worse than the paper's PHAST
    short = row(agg_with(paper / 2, paper, ALL_MODELS[:3]))
    assert short[1] == "no (7 models short)" and short[2].startswith("—") and short[-1].endswith("1 incomplete.")
