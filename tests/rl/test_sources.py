"""phast-rl beyond a simulated plant (issue 40): a machine behind a step function (q in, inputs out, no settable
state) and recordings from before the loop, with or without a plant."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from phast_model.cli.rl import main as rl_main  # noqa: E402
from phast_model.rl.plant import PlantSpec, make_plant  # noqa: E402
from phast_model.rl.sources import MachinePlant, join_recordings, load_machine, load_prior  # noqa: E402

BENCH = str(Path(__file__).resolve().parents[2] / "examples" / "machines" / "pendulum_bench.py")

DRIVERS = '''
import numpy as np
import gymnasium as gym


class GymLike(gym.Env):
    """A driver written as a Gymnasium env: obs q, action u, its own reset."""

    dt = 0.01
    observation_space = gym.spaces.Box(-np.inf, np.inf, (1,))
    action_space = gym.spaces.Box(-1.0, 1.0, (1,))

    def __init__(self, q0: float = 0.0) -> None:
        self.q = q0
        self.steps = 0
        self.closed = False

    def reset(self, *, seed=None, options=None):
        self.q = 0.0
        return np.array([self.q]), {}

    def step(self, u):
        self.q += 0.01 * float(np.asarray(u).reshape(-1)[0])
        self.steps += 1
        return np.array([self.q]), 0.0, False, False, {}

    def close(self):
        self.closed = True


def wrapped(q0: float = 0.0):
    """A driver as gym.make would hand it: behind a wrapper that does not forward ``dt``."""
    from gymnasium.wrappers import TimeLimit

    return TimeLimit(GymLike(q0), max_episode_steps=10_000)


class Fragile(GymLike):
    """Loses its encoder after ``fail_after`` steps."""

    def __init__(self, fail_after: int = 450) -> None:
        super().__init__()
        self.fail_after = fail_after

    def step(self, u):
        if self.steps >= self.fail_after:
            raise RuntimeError("encoder lost")
        return super().step(u)


class NoDt:
    def reset(self):
        return np.zeros(1)

    def step(self, u):
        return np.zeros(1)


class Broken:
    dt = 0.01

    def reset(self):
        return np.zeros(2)

    def step(self, u):
        return np.array([np.nan])
'''


@pytest.fixture()
def drivers(tmp_path: Path) -> str:
    path = tmp_path / "drivers.py"
    path.write_text(DRIVERS)
    return str(path)


def test_a_gymnasium_env_is_a_machine_and_its_state_is_never_set(drivers: str) -> None:
    plant = make_plant(PlantSpec("PHAST/Pendulum-v0", machine=f"{drivers}:GymLike", machine_kwargs={"q0": 0.4}))
    assert isinstance(plant, MachinePlant) and plant.m == 1 and plant.n == 1 and plant.dt == 0.01
    q, info = plant.reset(seed=0, options={"state": np.array([2.0, 1.0])})  # the requested start is ignored
    assert q.tolist() == [0.0] and info["state"][0] == 0.0 and math.isnan(info["state"][1])
    q, *_ = plant.step(np.array([50.0]))  # clipped at max_action 10
    assert q == pytest.approx([0.1])
    plant.close()
    assert plant.machine.closed and plant.machine.steps == 1


def test_bad_machines_are_clear_errors(drivers: str) -> None:
    with pytest.raises(ValueError, match="'dt'"):
        load_machine(f"{drivers}:NoDt")
    with pytest.raises(ValueError, match="no attribute 'Nope'"):
        load_machine(f"{drivers}:Nope")
    with pytest.raises(ValueError, match="does not take"):
        load_machine(f"{drivers}:GymLike", {"speed": 2})
    assert make_plant(PlantSpec("PHAST/Pendulum-v0", machine=f"{drivers}:wrapped")).dt == 0.01
    with pytest.raises(ValueError, match="give --dt 0.01"):
        make_plant(PlantSpec("PHAST/Pendulum-v0", dt=0.02, machine=f"{drivers}:GymLike"))
    plant = make_plant(PlantSpec("PHAST/Pendulum-v0", machine=f"{drivers}:Broken"))
    with pytest.raises(ValueError, match="2 measured coordinates, the rig description has n=1"):
        plant.reset()
    with pytest.raises(ValueError, match="non-finite"):
        plant.step(np.zeros(1))


def _prior_file(tmp_path: Path, T: int = 81, dt: float = 0.05) -> Path:
    rng = np.random.default_rng(0)
    t = np.arange(T) * dt
    q = np.stack([0.3 * np.sin(2.0 * t + k) for k in range(3)])[..., None]
    u = rng.normal(0, 1, (3, T - 1, 1))
    path = tmp_path / "prior.npz"
    np.savez(path, q=q, u=u, dt=dt, angle_dims=np.array([0]))
    return path


def test_recordings_are_cut_to_episodes_and_counted(tmp_path: Path) -> None:
    from phast_gym.systems.pendulum import Pendulum

    path = _prior_file(tmp_path)
    prior = load_prior(path, Pendulum(), [0], 0.05, 40)  # 3 x 80 intervals -> 2 pieces of 40 each
    assert prior.recordings["q"].shape == (6, 41, 1) and prior.recordings["u"].shape == (6, 40, 1)
    raw = np.load(path)
    assert np.allclose(prior.recordings["q"][1], raw["q"][0, 40:]) and np.allclose(prior.recordings["u"][1], raw["u"][0, 40:])
    assert prior.seconds == pytest.approx(3 * 80 * 0.05)
    joined = join_recordings(prior.recordings, prior.recordings)
    assert joined["q"].shape == (12, 41, 1)
    with pytest.raises(ValueError, match="sampled every 0.05 s, but the loop decides every 0.1 s"):
        load_prior(path, Pendulum(), [0], 0.1, 20)
    with pytest.raises(ValueError, match="fewer than one episode"):
        load_prior(path, Pendulum(), [0], 0.05, 90)


FAST = ["--agent", "sac", "--agent-steps", "160", "--refit-steps", "80", "--eval-every", "80", "--fit-epochs", "3", "--refit-epochs", "2",
        "--eval-trials", "1", "--eval-s", "1", "--no-progress"]


def test_phast_rl_learns_on_a_machine(tmp_path: Path) -> None:
    """The whole loop on the example bench (a hidden simulation behind reset/step): plant seconds counted, success
    judged on the measured angle, the policy written."""
    import torch

    torch.set_num_threads(1)
    out = tmp_path / "run"
    code = rl_main(["--machine", f"{BENCH}:make", "--machine-kwargs", '{"seed": 3}', "--env", "PHAST/Pendulum-v0",
                    "--budget-s", "4", "--episode-s", "2", "--out", str(out), *FAST])
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["plant_seconds"] == pytest.approx(4.0) and s["machine"].endswith("pendulum_bench.py:make")
    assert (out / "policy.zip").exists() and math.isfinite(s["rms_torque"]) and s["eval_trials"] == 1
    ms = s["controller_ms"]
    assert 0 < ms["mean"] <= ms["p99"] <= ms["max"]  # what the controller costs per step, against the machine's dt


def test_phast_rl_from_recordings_alone_and_with_a_plant(tmp_path: Path) -> None:
    import torch

    torch.set_num_threads(1)
    path = _prior_file(tmp_path)
    off = tmp_path / "offline"
    assert rl_main(["--recordings", str(path), "--offline", "--env", "PHAST/Pendulum-v0", "--episode-s", "2",
                    "--out", str(off), *FAST]) == 0
    s = json.loads((off / "summary.json").read_text())
    assert s["success"] is None and s["eval_trials"] == 0 and s["plant_seconds"] == pytest.approx(12.0)
    assert s["prior_seconds"] == pytest.approx(12.0) and len(s["iterations"]) == 1 and (off / "policy.zip").exists()
    on = tmp_path / "online"
    assert rl_main(["--recordings", str(path), "--env", "PHAST/Pendulum-v0", "--episode-s", "2", "--budget-s", "14",
                    "--out", str(on), *FAST]) == 0
    s = json.loads((on / "summary.json").read_text())
    assert s["plant_seconds"] == pytest.approx(14.0) and s["prior_seconds"] == pytest.approx(12.0)  # + one 2-s episode
    assert s["eval_trials"] == 1 and s["success"] is not None


def test_bad_source_options_are_refused(tmp_path: Path, drivers: str, capsys: pytest.CaptureFixture) -> None:
    cases = ((["--offline"], "--offline learns from --recordings"),
             (["--offline", "--recordings", "x.npz", "--machine", f"{drivers}:GymLike"], "give one of them"),
             (["--machine", f"{drivers}:NoDt"], "--machine: machine"),
             (["--excitation-std", "-1"], "torque_std must be a positive number"))
    for argv, words in cases:
        with pytest.raises(SystemExit) as exc:
            rl_main([*argv, "--out", str(tmp_path / "x")])
        assert exc.value.code == 2 and words in capsys.readouterr().err
    path = _prior_file(tmp_path)
    code = rl_main(["--recordings", str(path), "--budget-s", "10", "--episode-s", "2", "--out", str(tmp_path / "y"),
                    "--no-progress"])
    assert code == 2 and "exceed the budget" in capsys.readouterr().err


def test_a_run_deploys_its_controller_again(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """``load_controller`` rebuilds the agent and the learned hold from a run's files; ``--deploy`` runs them on a
    machine without learning; a run that does not fit the plant is refused."""
    import torch

    from phast_model.rl.hold import HybridPolicy
    from phast_model.rl.loop_report import load_config, load_controller

    torch.set_num_threads(1)
    run = tmp_path / "run"
    assert rl_main(["--env", "PHAST/Pendulum-v0", "--budget-s", "4", "--episode-s", "2", "--out", str(run), *FAST]) == 0
    cfg = load_config(run)
    assert cfg.plant.env_id == "PHAST/Pendulum-v0" and cfg.agent.steps == 160 and cfg.agent.net == (64, 64)
    policy = load_controller(run)
    assert isinstance(policy, HybridPolicy) and policy.hold is not None
    policy.reset(np.array([0.0]))
    assert np.all(np.abs(policy.act(np.array([0.0]))) <= 10.0)
    out = tmp_path / "deployed"
    assert rl_main(["--deploy", str(run), "--machine", f"{BENCH}:make", "--env", "PHAST/Pendulum-v0", "--eval-trials",
                    "2", "--eval-s", "1", "--out", str(out), "--no-progress"]) == 0
    ev = json.loads((out / "evaluation.json").read_text())
    assert ev["trials"] == 2 and ev["seconds"] == pytest.approx(2.0) and ev["run"] == str(run)
    assert not (out / "policy.zip").exists()  # nothing was learned
    code = rl_main(["--deploy", str(run), "--env", "PHAST/WindyCartPole-v0", "--env-kwargs", '{"actuated_dofs": [0]}',
                    "--eval-trials", "1", "--eval-s", "1", "--out", str(tmp_path / "bad"), "--no-progress"])
    assert code == 2 and "coordinates" in capsys.readouterr().err
    (run / "config.json").write_text('{"plant": {"env_id": "PHAST/Pendulum-v0", "colour": 1}}')
    with pytest.raises(ValueError, match=r"unknown keys \['colour'\]"):
        load_config(run)


def test_a_machine_that_fails_mid_loop_loses_no_recording(tmp_path: Path, drivers: str,
                                                          capsys: pytest.CaptureFixture) -> None:
    """The rig fails in the first policy episode: the two excitation episodes recorded before are written to
    recordings.npz, the message says how to continue, and --recordings accepts the file."""
    import torch

    torch.set_num_threads(1)
    out = tmp_path / "run"
    code = rl_main(["--machine", f"{drivers}:Fragile", "--env", "PHAST/Pendulum-v0", "--budget-s", "6", "--episode-s", "2",
                    "--out", str(out), *FAST])
    err = capsys.readouterr().err
    assert code == 2 and "RuntimeError: encoder lost" in err and "--recordings" in err
    rec = np.load(out / "recordings.npz")
    assert rec["q"].shape == (2, 41, 1) and rec["u"].shape == (2, 40, 1)
    assert not (out / "summary.json").exists()
    from phast_gym.systems.pendulum import Pendulum

    assert load_prior(out / "recordings.npz", Pendulum(), [0], 0.05, 40).seconds == pytest.approx(4.0)
