"""A model file's models are scored as MuJoCo simulates them written back (phast_model.mismatch.written)."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from phast_gym.systems.mjcf import mjcf_system  # noqa: E402
from phast_model.identify.mujoco_sim import rollout_q  # noqa: E402
from phast_model.identify.shooting import simulate_qv  # noqa: E402
from phast_model.identify.simulators import load_simulator  # noqa: E402
from phast_model.mismatch.vocabulary.registry import law_terms, mujoco_vocabulary  # noqa: E402
from phast_model.mismatch.vocabulary.terms import AugmentedSystem, Term  # noqa: E402
from phast_model.mismatch.written import in_mujoco, written_form  # noqa: E402
from tests.identify.test_mjcf import ARM  # noqa: E402  (a 4-joint arm: shoulder, elbow, slide, wrist)


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    path = tmp_path_factory.mktemp("written") / "arm4.xml"
    path.write_text(ARM)
    return path


def _rollout(system, rng_seed: int = 0):
    rng = np.random.default_rng(rng_seed)
    q0, v0 = rng.uniform(-0.5, 0.5, (3, 4)), rng.uniform(-1.0, 1.0, (3, 4))
    u = rng.uniform(-0.5, 0.5, (3, 40, 4))
    return q0, v0, u, simulate_qv(system, q0, v0, 40, u, 0.01, 2)


def test_nominal_model_is_muJoCos_own_rollout(arm):
    system = mjcf_system(arm)()
    written = in_mujoco(system)
    assert written is not system and hasattr(written, "external_rollout")
    q0, v0, u, q = _rollout(written)
    direct = rollout_q(str(arm), q0, v0, u[..., list(system.actuated_dofs)], 0.01, 40)
    assert np.max(np.abs(q - direct)) < 1e-5  # the file through MjSpec's round trip (printed digits), not bit-equal


def test_terms_and_parameters_are_written_as_attributes(arm):
    base = mjcf_system(arm)(**{"link2.mass": 0.6})
    aug = AugmentedSystem(base, [Term("coulomb_friction", 1, 0.3), Term("viscous_damping", 0, 0.02),
                                 Term("armature", 3, 0.01)])
    tree, params, edits = written_form(aug)
    assert params == {"link2.mass": 0.6}
    assert {(e.target, e.attr, e.value) for e in edits} == {("elbow", "frictionloss", 0.3),
                                                           ("shoulder", "damping", 0.02), ("wrist", "armature", 0.01)}
    written = in_mujoco(aug)
    assert written.params["elbow.frictionloss"] == pytest.approx(0.3)
    assert written.params["shoulder.damping"] == pytest.approx(0.12)
    assert written.params["wrist.armature"] == pytest.approx(0.01)
    assert written.params["link2.mass"] == pytest.approx(0.6)
    # MuJoCo's frictionloss holds a slow joint still where a smoothed sign(qdot) under explicit RK4 lets it creep:
    # the two agree away from rest
    q_ours = _rollout(aug)[3]
    q_mj = _rollout(written)[3]
    assert np.all(np.isfinite(q_mj)) and np.max(np.abs(q_mj - q_ours)) < 0.1


def test_a_term_muJoCo_lacks_keeps_the_tools_integrator(arm):
    aug = AugmentedSystem(mjcf_system(arm)(), [Term("quadratic_drag", 0, 0.1)])
    assert written_form(aug) is None and in_mujoco(aug) is aug
    pendulum = load_simulator("PHAST/Pendulum-v0").build()
    assert in_mujoco(pendulum) is pendulum


def test_model_files_default_to_the_friction_muJoCo_simulates():
    vocab = mujoco_vocabulary()
    assert set(law_terms(vocab)) == {"viscous_damping", "coulomb_friction"}
    assert {"armature", "actuator_gain", "input_delay"} <= set(vocab)
