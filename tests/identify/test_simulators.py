"""``--sim`` resolution: env ids, ``module:Class`` and a user's ``rig.py:Class``, with clear errors."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

from phast_gym.integrate import simulate
from phast_gym.systems import NUMPY, Pendulum
from phast_model.identify.simulators import load_simulator
from phast_model.mismatch.vocabulary.terms import AugmentedSystem, Term
from tests import ROOT

EXAMPLE = ROOT / "examples" / "rigs" / "torsion_pendulum.py"
DOC = ROOT / "docs" / "describe_your_rig.md"

SPRING_RIG = '''
import numpy as np

from phast_gym.systems import NUMPY, Param, System, const_like


class CartOnSpring(System):
    """A cart on a rail held by a hardening spring: H = p^2/(2m) + k x^2/2 + k3 x^4/4."""

    name = "cart_on_spring"
    n = 1
    dt = 0.02
    coordinate_names = ("x",)
    PARAMS = {
        "mass": Param(2.0, "cart mass [kg]"),
        "k": Param(5.0, "linear spring [N/m]"),
        "k3": Param(1.0, "cubic spring [N/m^3]", "nonnegative"),
        "c": Param(0.1, "viscous friction [N s/m]", "nonnegative"),
    }

    def potential(self, q, xp=NUMPY):
        return 0.5 * self.k * q[0] ** 2 + 0.25 * self.k3 * q[0] ** 4

    def grad_potential(self, q, xp=NUMPY):
        return (self.k * q[0] + self.k3 * q[0] ** 3,)

    def mass_matrix(self, q, xp=NUMPY):
        return ((const_like(q[0], self.mass),),)

    def velocity(self, q, p, xp=NUMPY):
        return (p[0] / self.mass,)

    def damping(self, q, xp=NUMPY):
        return (const_like(q[0], self.c),)

    def sample_initial(self, rng, size):
        return np.stack([rng.normal(0.0, 0.5, size), rng.normal(0.0, 1.0, size)], axis=1)


class NotARig:
    pass


class HalfWritten(System):
    name = "half_written"
    PARAMS = {}

    def sample_initial(self, rng, size):
        return np.zeros((size, 2))

    def potential(self, q, xp=NUMPY):
        return 0.0 * q[0]

    def grad_potential(self, q, xp=NUMPY):
        return (0.0 * q[0],)

    def mass_matrix(self, q, xp=NUMPY):
        return ((1.0 + 0.0 * q[0],),)
'''


@pytest.fixture
def rig_file(tmp_path: Path) -> Path:
    path = tmp_path / "rig.py"
    path.write_text(SPRING_RIG)
    return path


def _energy_drift(system, x0: np.ndarray, n_steps: int) -> float:
    n = system.n
    tr = simulate(system, x0, n_steps)
    H = system.hamiltonian(tuple(tr[..., i] for i in range(n)), tuple(tr[..., n + i] for i in range(n)), NUMPY)
    return float(np.max(np.abs(H - H[:, :1])))


def test_user_file_loads_by_path_and_builds_with_kwargs(rig_file: Path) -> None:
    sim = load_simulator(f"{rig_file}:CartOnSpring", {"k": 7.0, "c": 0.0})
    system = sim.build()
    assert type(system).__name__ == "CartOnSpring" and system.k == 7.0 and system.mass == 2.0
    assert sim.build(mass=3.0).mass == 3.0 and sim.build(mass=3.0).k == 7.0  # calibrated overrides on top of the user's kwargs
    assert sim.numeric_params() == {"mass": 2.0, "k": 7.0, "k3": 1.0, "c": 0.0}
    x0 = system.sample_initial(np.random.default_rng(0), 4)
    assert _energy_drift(system, x0, 200) < 1e-8
    aug = AugmentedSystem(system, [Term("coulomb_friction", 0, 0.2), Term("armature", 0, 0.5)])
    assert aug.mass_matrix((np.zeros(1),))[0][0] == pytest.approx(2.5)


def test_module_class_and_env_id() -> None:
    sim = load_simulator("phast_gym.systems:Pendulum", {"length": 0.8})
    assert isinstance(sim.build(), Pendulum) and sim.build().length == 0.8
    env = load_simulator("PHAST/DoublePendulum-v0", {"coordinates": "relative", "com1": 0.4, "inertia1": 0.3, "obs_noise_std": 0.1})
    system = env.build()
    assert system.coordinates == "relative" and system.i1 == 0.3
    params = env.numeric_params()
    assert "coordinates" not in params and params["com1"] == 0.4 and params["mass1"] == 1.0
    assert load_simulator(Pendulum).build().mass == 1.0


@pytest.mark.parametrize(("spec", "kwargs", "match"), [
    ("{dir}/missing.py:Rig", None, r"file '.*missing\.py' not found"),
    ("{dir}/rig.py:NoSuchRig", None, r"has no attribute 'NoSuchRig' \(System subclasses there: \['CartOnSpring', 'HalfWritten'\]\)"),
    ("{dir}/rig.py:NotARig", None, "is not a phast_gym.systems.System subclass"),
    ("{dir}/rig.py:np", None, "is not a phast_gym.systems.System subclass"),
    ("{dir}/rig.py:CartOnSpring", {"stiffness": 1.0}, r"failed to build with kwargs .*unknown parameter\(s\) \['stiffness'\]"),
    ("{dir}/rig.py:CartOnSpring", {"mass": -1.0}, r"failed to build .*mass=-1.0 must be > 0"),
    ("{dir}/rig.py:HalfWritten", None, "HalfWritten.velocity failed: NotImplementedError"),
    ("phast_gym.systems:PredatorPrey", None, "not a port-Hamiltonian system"),
    ("phast_gym.no_such_module:Rig", None, "cannot import module 'phast_gym.no_such_module'"),
    ("PHAST/NoSuchEnv-v0", None, "unknown simulator 'PHAST/NoSuchEnv-v0'"),
    ("PHAST/DoublePendulum-v0", {"coordinates": "foo"}, r"coordinates='foo' must be one of \['absolute', 'relative'\]"),
    ("rig.py:", None, "expected an env id, 'package.module:Class' or 'path/to/file.py:Class'"),
])
def test_errors_name_the_problem(rig_file: Path, spec: str, kwargs: dict | None, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        load_simulator(spec.format(dir=rig_file.parent), kwargs)


def test_broken_file_reports_the_import_error(tmp_path: Path) -> None:
    path = tmp_path / "broken.py"
    path.write_text("import numpy as np\nraise RuntimeError('calibration table missing')\n")
    with pytest.raises(ValueError, match=r"importing .*broken\.py' failed: RuntimeError: calibration table missing"):
        load_simulator(f"{path}:Rig")


def test_malformed_method_is_reported(tmp_path: Path) -> None:
    path = tmp_path / "bad.py"
    path.write_text(SPRING_RIG + textwrap.dedent('''
        class TwoForOne(CartOnSpring):
            def grad_potential(self, q, xp=NUMPY):
                return (q[0], q[0])
    '''))
    with pytest.raises(ValueError, match=r"TwoForOne.grad_potential must return a tuple of n=1 components"):
        load_simulator(f"{path}:TwoForOne")


# --------------------------------------------------------------------------- the documented example
def test_doc_shows_the_example_file_verbatim() -> None:
    """docs/describe_your_rig.md quotes examples/rigs/torsion_pendulum.py exactly (the file the next test runs)."""
    m = re.search(r"<!-- example: examples/rigs/torsion_pendulum.py -->\n```python\n(.*?)```", DOC.read_text(), re.S)
    assert m is not None, "the doc's example block (marked <!-- example: ... -->) is missing"
    assert m.group(1) == EXAMPLE.read_text()


def test_documented_example_rig_works() -> None:
    sim = load_simulator(f"{EXAMPLE}:TorsionPendulum", {"friction": 0.0})
    system = sim.build()
    x0 = system.sample_initial(np.random.default_rng(1), 6)
    assert _energy_drift(system, x0, 300) < 1e-7
    # with friction and a motor torque: dH/dt = -b qdot^2 + qdot u
    damped = sim.build(friction=0.05)
    q, p, u = (x0[:, 0],), (x0[:, 1],), (np.full(6, 0.3),)
    qd, pd = damped.rhs(q, p, u, NUMPY)
    eps = 1e-6
    H = [damped.hamiltonian((q[0] + s * eps * qd[0],), (p[0] + s * eps * pd[0],)) for s in (-1, 1)]
    diss, supplied = damped.power_balance(q, p, u)
    np.testing.assert_allclose((H[1] - H[0]) / (2 * eps), supplied - diss, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(diss, 0.05 * qd[0] ** 2, rtol=1e-12)
