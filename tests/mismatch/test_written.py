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


def test_model_files_default_to_the_terms_muJoCo_simulates():
    """No state-dependent force without an attribute (the fits then run on MuJoCo); sensor and port maps, delays and
    a constant force stay."""
    vocab = set(mujoco_vocabulary())
    assert "cubic_stiffness" not in vocab and "quadratic_drag" not in vocab
    assert {"sensor_offset", "sensor_delay", "actuator_deadzone", "constant_force", "input_delay"} <= vocab


def test_terms_without_an_attribute_act_around_muJoCos_rollout(arm):
    """A constant force (qfrc_applied), a deadzone of the control, a sensor offset and both delays, with a rotor
    inertia written into the file: MuJoCo's rollout follows the tool's own integrator of the same model."""
    from phast_model.mismatch.written import simulated_copy

    terms = [Term("constant_force", 0, 0.05), Term("sensor_offset", 1, 0.01), Term("actuator_deadzone", 0, 0.05),
             Term("armature", 1, 0.003), Term("input_delay", 0, 0.004), Term("sensor_delay", 1, 0.002)]
    aug = AugmentedSystem(mjcf_system(arm)(), terms)
    simulated = in_mujoco(aug)
    assert isinstance(simulated, AugmentedSystem) and simulated.terms == aug.terms
    assert getattr(simulated, "external_rollout", None) is not None
    rng = np.random.default_rng(0)
    n = aug.n
    q0, v0, u = rng.normal(0, 0.3, (4, n)), rng.normal(0, 0.3, (4, n)), rng.normal(0, 0.2, (4, 60, n))
    ours = simulate_qv(aug, q0, v0, 60, u, 0.01, 10)
    theirs = simulate_qv(simulated, q0, v0, 60, u, 0.01, 10)
    assert np.max(np.abs(ours - theirs)) < 1e-3 < np.max(np.abs(ours - q0[:, None]))
    assert simulated_copy(AugmentedSystem(mjcf_system(arm)(), [Term("cubic_stiffness", 0, 1.0)])) is None


def test_a_family_on_muJoCo_refuses_what_muJoCo_refuses(arm):
    """A trial value MuJoCo will not compile (a negative total rotor inertia) gives a rollout no fit accepts, not a
    switch to the tool's own integrator."""
    from phast_model.mismatch.written import family_engine

    refused = family_engine(AugmentedSystem(mjcf_system(arm)(), [Term("armature", 0, 0.0)]))
    bad = AugmentedSystem(mjcf_system(arm)(), [Term("armature", 0, 0.01)])
    object.__setattr__(bad.terms[0], "coefficient", -1.0)  # past Term's own check, as a trial step can be
    assert getattr(refused, "external_rollout", None) is not None
    out = simulate_qv(family_engine(bad), np.zeros((2, bad.n)), np.zeros((2, bad.n)), 5, None, 0.01, 1)
    assert np.all(np.isnan(out))


def test_a_written_model_whose_values_are_refused_is_an_error_the_report_can_name(arm):
    """A text MuJoCo compiles but whose values the file's parameters refuse (a negative total damping) raises
    ModelFileError, which the report turns into a note instead of a failed analysis."""
    from phast_gym.systems.mjcf_tree import ModelFileError
    from phast_model.mismatch.written import text_simulated

    text = arm.read_text().replace('damping="0.1" armature="0.01"', 'damping="-0.01" armature="0.01"', 1)
    assert text != arm.read_text()
    with pytest.raises(ModelFileError, match="refused"):
        text_simulated(text)


def test_a_fit_in_muJoCo_simulates_and_writes_the_nearest_rigid_body_and_refuses_what_muJoCo_refuses(arm):
    """Every principal moment of link2 fitted and past A + B >= C: MuJoCo simulates, and the file gets, the body with
    the smaller other moment raised to the bound, with a note; a value MuJoCo refuses outright (a negative total
    rotor inertia) rolls out NaN in a fit (in_engine), never on the tool's integrator."""
    from phast_model.identify.mjcf_write import calibrated_xml
    from phast_model.mismatch.written import in_engine, mujoco_runs

    sim = load_simulator(str(arm))
    moments = {"link2.inertia_x": 0.03, "link2.inertia_y": 0.016, "link2.inertia_z": 0.005}  # 0.021 < 0.03
    assert mujoco_runs(in_engine(sim.build(**moments)))
    written = calibrated_xml(mjcf_system(arm).TREE, moments)
    assert any("link2.inertia_z raised 0.005 -> 0.014" in n and "the fitted moments broke it" in n
               for n in written.notes)
    bad = AugmentedSystem(mjcf_system(arm)(), [Term("armature", 0, 0.01)])
    object.__setattr__(bad.terms[0], "coefficient", -1.0)  # past Term's own check, as a trial step can be
    refused = in_engine(bad)
    assert not mujoco_runs(refused)
    assert np.all(np.isnan(simulate_qv(refused, np.zeros((2, bad.n)), np.zeros((2, bad.n)), 5, None, 0.01, 1)))
