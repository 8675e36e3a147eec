"""MuJoCo's own sysid as a peer (benchmarks/sysid_peer.py, a library module of the benchmarks): it recovers a
pendulum's damping from clean recordings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

sysid = pytest.importorskip("mujoco.sysid")
if not hasattr(sysid, "optimize"):  # the package imports without its extra's dependencies, then holds nothing
    pytest.skip("mujoco.sysid needs the mujoco[sysid] extra", allow_module_level=True)

from benchmarks.sysid_peer import fit_with_sysid, zoh_control  # noqa: E402
from phast_model.identify.mujoco_sim import rollout_q  # noqa: E402

PENDULUM = """<mujoco model="pendulum">
  <option timestep="0.002" integrator="RK4"><flag contact="disable"/></option>
  <worldbody>
    <body name="link">
      <joint name="hinge" type="hinge" axis="0 1 0" damping="{damping}"/>
      <inertial pos="0 0 -0.25" mass="1" diaginertia="0.005 0.005 0.001"/>
    </body>
  </worldbody>
  <actuator><motor name="motor" joint="hinge"/></actuator>
</mujoco>
"""
TRUE_DAMPING = 0.05


def _recordings(real: Path, n: int = 3, T: int = 201, dt: float = 0.01) -> dict[str, object]:
    rng = np.random.default_rng(0)
    t = np.arange(T - 1) * dt
    u = np.stack([0.8 * np.sin(2 * np.pi * rng.uniform(0.3, 1.5) * t + rng.uniform(0, 2 * np.pi))[:, None]
                  for _ in range(n)])
    q = rollout_q(str(real), rng.uniform(-1, 1, (n, 1)), np.zeros((n, 1)), u, dt, T - 1)
    return {"q": q, "u": u, "dt": dt}


def test_recovers_pendulum_damping(tmp_path: Path) -> None:
    nominal, real = tmp_path / "nominal.xml", tmp_path / "real.xml"
    nominal.write_text(PENDULUM.format(damping=0))
    real.write_text(PENDULUM.format(damping=TRUE_DAMPING))
    res = fit_with_sysid(nominal, _recordings(real), train_indices=[0, 1, 2], params="joints")
    d = res.values["hinge.damping"]
    assert abs(d.fitted - TRUE_DAMPING) <= 0.05 * TRUE_DAMPING, d
    assert d.ci95 is not None and np.isfinite(d.ci95), res.intervals_error
    assert res.cost_final < 0.01 * res.cost_start
    import mujoco

    written = mujoco.MjModel.from_xml_string(res.xml)  # the fitted value is written into the model file
    assert written.dof_damping[0] == pytest.approx(d.fitted, rel=1e-6) and written.nsensor == 0


def test_zoh_control_on_the_timestep_grid() -> None:
    tau = np.array([0.0, 0.0101, 0.0199, 0.03])  # jittered sample times
    u = np.array([[1.0], [2.0], [3.0]])
    grid, ctrl = zoh_control(tau, u, 0.005)
    assert np.allclose(grid, np.arange(7) * 0.005)
    assert ctrl[:, 0].tolist() == [1, 1, 1, 2, 3, 3, 3]  # u[k] from tau[k] on
