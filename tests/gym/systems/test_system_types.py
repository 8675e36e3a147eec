"""The static types of the systems agree with what runs (``make typecheck`` relies on them)."""

from __future__ import annotations

import math
import typing

import numpy as np
import pytest

from phast_gym.systems import NUMPY, SCALAR, SYSTEMS, TORCH, PairParticles, System
from phast_gym.systems.base import ArrayNamespace

NAMESPACE_MEMBERS = [name for name in dir(ArrayNamespace) if not name.startswith("_")] + ["name"]


@pytest.mark.parametrize("cls", sorted(SYSTEMS.values(), key=lambda c: c.name), ids=lambda c: c.name)
def test_every_parameter_has_a_declared_type(cls: type[System]) -> None:
    """The constructor sets each PARAMS entry as an attribute; its class declares the attribute's type, and the
    default value fits it (a choice parameter is a str, a None default an optional float)."""
    hints = typing.get_type_hints(cls)
    missing = sorted(set(cls.PARAMS) - set(hints))
    assert not missing, f"{cls.__name__}: declare {missing} as annotated class attributes"
    system = cls()
    for key, spec in cls.PARAMS.items():
        value = getattr(system, key)
        hint = hints[key]
        if spec.choices:
            assert hint is str, (key, hint)
        elif spec.default is None and value is None:
            assert hint == float | None, (key, hint)
        else:
            assert isinstance(value, float), (key, value)


def test_pair_particles_declare_the_shared_parameters() -> None:
    hints = typing.get_type_hints(PairParticles)
    assert hints["mass"] is float and hints["gamma"] is float


@pytest.mark.parametrize("xp", [SCALAR, NUMPY, TORCH], ids=lambda xp: xp.name)
def test_namespaces_provide_the_protocol(xp: ArrayNamespace) -> None:
    assert {"sin", "cos", "sqrt", "exp", "tanh", "abs", "log", "sign", "where", "clip_min"} <= set(NAMESPACE_MEMBERS)
    x: typing.Any = 0.5
    if xp is NUMPY:
        x = np.array(0.5)
    elif xp is TORCH:
        torch = pytest.importorskip("torch")
        x = torch.tensor(0.5, dtype=torch.float64)
    for member in NAMESPACE_MEMBERS:
        assert hasattr(xp, member), member
    assert float(xp.sin(x)) == pytest.approx(math.sin(0.5))
    assert float(xp.clip_min(x, 1.0)) == 1.0
