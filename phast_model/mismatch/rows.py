"""The typed rows the stages hand each other and the report: a calibrated parameter, a term (missing physics), an
alternative explanation.

They are frozen; a stage that revises a row builds a new one (:func:`dataclasses.replace`).  ``to_dict`` gives the
report.json object of docs/mismatch.md, with its keys in the order the report has always written them (an optional
field that is None is left out, not written as null).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any


def _present(pairs: Sequence[tuple[str, object]]) -> dict[str, Any]:
    """The (key, value) pairs whose value is not None, in order."""
    return {k: v for k, v in pairs if v is not None}


def param_value(value: object) -> float:
    """A numeric parameter's value as the simulator holds it (an int stays an int, as the report has always written
    it)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"parameter value {value!r} is not a number")
    return value


@dataclass(frozen=True)
class ParamRow:
    """report.sim.calibrated[name]: the nominal and fitted value of one parameter of the simulator.

    A changed parameter has a 95% interval and its relative change; a parameter held at its nominal value has no
    interval and a note saying why."""

    nominal: float
    fitted: float
    ci95: tuple[float, float] | None = None
    relative_change: float | None = None
    equivalent_changes: str | None = None  # other parameters whose change the recordings cannot tell from this one's
    note: str | None = None
    #: for a value fitted under a prior (a CAD body value): the share of what is known of it that comes from the
    #: recordings, 1 - posterior variance / prior variance (below a half: mostly the file's value)
    data_share: float | None = None

    @property
    def from_data(self) -> bool:
        """A changed value the recordings, not a prior, mostly decide, and whose interval excludes the file's value
        where a prior entered."""
        if self.ci95 is None or self.data_share is None:
            return self.changed
        lo, hi = sorted(self.ci95)
        return self.data_share >= 0.5 and not lo <= self.nominal <= hi

    @classmethod
    def held(cls, nominal: float, note: str) -> ParamRow:
        """A parameter left at its nominal value, with the reason."""
        return cls(nominal, nominal, None, note=note)

    @property
    def changed(self) -> bool:
        return self.ci95 is not None

    def to_dict(self) -> dict[str, Any]:
        return {"nominal": self.nominal, "fitted": self.fitted, "ci95": None if self.ci95 is None else list(self.ci95),
                **_present([("relative_change", self.relative_change), ("equivalent_changes", self.equivalent_changes),
                            ("note", self.note), ("data_share", self.data_share)])}


@dataclass(frozen=True)
class Alternative:
    """One entry of a term's ``alternatives``: another term or a parameter change with the same effect on the
    recordings (shooting), the parameter changes a port gain stands for, or a friction law nearly as predictive (weak
    form).  Exactly one of ``term``, ``parameter`` and ``law`` is set."""

    term: str | None = None
    coordinate: int | None = None
    parameter: str | None = None
    law: str | None = None
    value: float | None = None  # the parameter's value that has the same effect
    coefficient: float | None = None  # the other term's coefficient that has the same effect
    similarity: float | None = None  # |cosine| of the two shooting signatures
    note: str | None = None

    @property
    def name(self) -> str:
        """The term, parameter or law it names."""
        return next((s for s in (self.term, self.parameter, self.law) if s is not None), "")

    def to_dict(self) -> dict[str, Any]:
        return _present([("law", self.law), ("term", self.term), ("coordinate", self.coordinate),
                         ("parameter", self.parameter),
                         ("value", self.value), ("coefficient", self.coefficient), ("similarity", self.similarity),
                         ("note", self.note)])


@dataclass(frozen=True)
class TermRow:
    """report.missing_physics[i] (and details.unconfirmed_terms[i]): one term of the vocabulary the simulator leaves
    out.

    ``explains``: the share of the nominal fit's excess chi^2 the term removes (shooting; None from the weak form).
    ``evidence``: how the weak form chose it (None from the shooting selection)."""

    term: str
    coordinate: int
    component: str
    coefficient: float
    ci95: tuple[float, float]
    expression: str
    explains: float | None = None
    alternatives: tuple[Alternative, ...] = ()
    stribeck_velocity: float | None = None  # the terms whose kind has a velocity
    evidence: str | None = None
    joint: str | None = None  # a MuJoCo model's joint name (set with ``mjcf``: the attribute that expresses the term)
    mjcf: str | None = None

    @property
    def label(self) -> str:
        return f"{self.term}[{self.coordinate}]"

    def to_dict(self) -> dict[str, Any]:
        joint = {} if self.joint is None else {"joint": self.joint, "mjcf": self.mjcf}
        head = {"term": self.term, "coordinate": self.coordinate, **joint, "component": self.component,
                "coefficient": self.coefficient, "ci95": list(self.ci95)}
        velocity = _present([("stribeck_velocity", self.stribeck_velocity)])
        expression = {"expression": self.expression}
        # report.json's key order: a shooting row writes the velocity before the expression, a weak-form row (the one
        # with evidence) after it
        middle = {**velocity, **expression} if self.evidence is None else {**expression, **velocity}
        return {**head, **middle, "explains": self.explains, "alternatives": [a.to_dict() for a in self.alternatives],
                **_present([("evidence", self.evidence)])}
