"""phast-rl on a rig of the user's own: a ``path/to/rig.py:Class`` System subclass as the plant (named as for
``phast-mismatch --sim``), the loop's rig description by default, its quiet criterion from its own LQG floor."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from phast_model.cli.rl import main as rl_main
from phast_model.rl.plant import PlantSpec, make_plant, plant_system, quiet_u_tol

RIG = '''
from phast_gym.systems.base import Param
from phast_gym.systems.pendulum import Pendulum


class HeavyPendulum(Pendulum):
    """A user's pendulum rig: a 1.5-kg bob."""

    PARAMS = {**Pendulum.PARAMS, "mass": Param(1.5, "bob mass m [kg]")}


class Cart(Pendulum):
    """Not a pendulum on the upright task: no angle."""

    name = "cart_only"
    angle_dims = ()
'''


@pytest.fixture()
def rig(tmp_path: Path) -> str:
    path = tmp_path / "rig.py"
    path.write_text(RIG)
    return str(path)


def test_a_user_rig_class_is_a_plant_with_its_own_physics(rig: str) -> None:
    spec = PlantSpec(f"{rig}:HeavyPendulum")
    system = plant_system(spec)
    assert type(system).__name__ == "HeavyPendulum" and system.mass == 1.5 and system.dt == spec.dt
    plant = make_plant(spec)
    q, info = plant.reset(seed=0, options={"state": np.array([0.3, 0.0])})
    assert q.shape == (1,) and info["state"][0] == pytest.approx(0.3)
    assert quiet_u_tol(spec) == 0.25  # a 1-dof pendulum keeps the protocol's limit
    assert plant_system(PlantSpec(f"{rig}:HeavyPendulum", {"mass": 2.0})).mass == 2.0


def test_phast_rl_runs_the_loop_on_a_user_rig(rig: str, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    import torch

    torch.set_num_threads(1)
    out = tmp_path / "run"
    code = rl_main(["--agent", "sac", "--env", f"{rig}:HeavyPendulum", "--budget-s", "4", "--episode-s", "2",
                    "--agent-steps", "160",
                    "--refit-steps", "80", "--eval-every", "80", "--fit-epochs", "3", "--refit-epochs", "2",
                    "--eval-trials", "1", "--eval-s", "1", "--out", str(out), "--no-progress"])
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["plant_seconds"] == pytest.approx(4.0) and s["env"].endswith("rig.py:HeavyPendulum")
    assert (out / "policy.zip").exists() and math.isfinite(s["rms_torque"])


def test_a_bad_user_rig_is_a_clear_error(rig: str, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    for env, words in ((f"{rig}:NoSuchClass", "NoSuchClass"), (f"{rig}:Cart", "no angle")):
        with pytest.raises(SystemExit) as exc:
            rl_main(["--env", env, "--out", str(tmp_path / "x")])
        assert exc.value.code == 2 and words in capsys.readouterr().err
