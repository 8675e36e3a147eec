"""One benchmark run's full configuration and its stable content hash.

A run is identified by :func:`run_key` = sha256 of the canonical JSON of every
field that can change its result (env, model, seed, data protocol, training
budget, evaluation protocol, model overrides, harness version, and the model's
revision where it has one).  Identical
configurations always hash the same across processes and machines, so a finished
run is found again and never redone, and changing any field starts a new run.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from typing import Any, TypedDict

#: bump when the meaning of a stored result changes (new metrics protocol, ...)
HARNESS_VERSION = 1

#: per model, bumped when a code change alters what its runs train or output (absent = 1); it enters the hash of
#: that model's runs only, so their stored results are redone and every other model's stay valid.  What each bump
#: was: docs/phast_model.md, "Benchmark model revisions".
MODEL_REVISIONS: dict[str, int] = {"transformer": 2, "phast-known": 3, "phast-partial": 5, "phast-unknown": 5}
#: (model, env id) -> revision, where a change touches one env's runs of a model only (overrides MODEL_REVISIONS)
ENV_MODEL_REVISIONS: dict[tuple[str, str], int] = {
    ("phast-partial", "PHAST/WindyPendulum-v0"): 3, ("phast-known", "PHAST/WindyCartPole-v0"): 4,
    **{(m, "PHAST/PredatorPrey-v0"): 6 for m in ("phast-known", "phast-partial", "phast-unknown")},
    **{("phast-unknown", f"PHAST/{e}-v0"): 4
       for e in ("WindyCartPole", "DoublePendulum", "DampedDoublePendulum", "WindyDoublePendulum")}}


def model_revision(model: str, env_id: str) -> int | None:
    """The revision of ``model``'s runs on ``env_id`` (None: never revised)."""
    return ENV_MODEL_REVISIONS.get((model, env_id), MODEL_REVISIONS.get(model))

PHAST_MODELS = ("phast-known", "phast-partial", "phast-unknown")
BASELINE_MODELS = ("gru", "lstm", "transformer", "s5", "linoss", "dlinoss", "vpt")
#: ``--models all``: the paper's grid (DHNN is the full-state ablation, asked for by name)
ALL_MODELS = PHAST_MODELS + BASELINE_MODELS
KNOWN_MODELS = ALL_MODELS + ("dhnn",)


@dataclass(frozen=True)
class RunSpec:
    """Everything that defines one (env, model, seed) run.  Defaults = the paper's protocol."""

    env_id: str
    model: str
    seed: int = 0
    epochs: int = 50
    n_train: int = 1000
    n_val: int = 200
    n_test: int = 200
    T: int = 200
    data_seed: int = 42
    horizons: tuple[int, ...] = (10, 50, 100)
    burn_in: int = 10
    full_state: bool = False
    train: dict[str, Any] = field(default_factory=dict)  # TrainConfig overrides (batch_size, lr, ...)
    model_kw: dict[str, Any] = field(default_factory=dict)  # constructor overrides (d_model, ...)
    version: int = HARNESS_VERSION

    def __post_init__(self) -> None:
        if self.model not in KNOWN_MODELS:
            raise ValueError(f"unknown model {self.model!r}; known: {', '.join(KNOWN_MODELS)}")
        for name in ("epochs", "n_train", "n_val", "n_test"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.T < self.burn_in + 2:
            raise ValueError(f"T = {self.T} too short for burn-in {self.burn_in}")
        if not self.horizons or min(self.horizons) < 1:
            raise ValueError(f"horizons must be positive, got {self.horizons}")

    def config(self) -> dict[str, Any]:
        """Canonical JSON-ready configuration (the hashed content)."""
        d = asdict(self)
        d["horizons"] = [int(h) for h in self.horizons]
        rev = model_revision(self.model, self.env_id)
        if rev is not None:
            d["model_revision"] = rev
        return json.loads(json.dumps(d, sort_keys=True))

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> RunSpec:
        """The spec of a configuration; its ``model_revision`` (derived, not a field) is dropped."""
        cfg = dict(cfg)
        cfg.pop("model_revision", None)
        cfg["horizons"] = tuple(cfg.get("horizons", (10, 50, 100)))
        return cls(**cfg)


class RunRecord(TypedDict, total=False):
    """One run's record: what its result file holds (:func:`phast_model.bench.runner.write_record`), plus how this
    delivery got it (``status``: ran, cached or failed; ``persisted_by``) and, for a failed run, its error."""

    key: str
    env: str | None  # None: a failed run whose config lacks it
    model: str | None
    seed: int | None
    config: dict[str, Any]  # :meth:`RunSpec.config`
    metrics: dict[str, Any]  # the test metrics, JSON values (NaN as None)
    params: int
    best_val: float | None
    fit_wall_time_s: float
    wall_time_s: float
    history: list[dict[str, Any]]
    git_commit: str | None
    host: str
    python: str
    torch: str
    threads: int
    finished_utc: str
    status: str
    persisted_by: str
    error: str
    traceback: str


def run_key(spec: RunSpec) -> str:
    """Stable 16-hex-digit hash of the full configuration."""
    blob = json.dumps(spec.config(), sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


#: most seeds one grid may ask for (a typo such as 0-100000000 is refused at once instead of running for minutes)
MAX_SEEDS = 10_000


def parse_seeds(text: str, max_seeds: int = MAX_SEEDS) -> list[int]:
    """``"0-4"`` -> [0..4]; ``"0,2,5"`` -> [0, 2, 5]; mixes allowed (``"0-2,7"``); more than ``max_seeds`` seeds is
    a ValueError (checked on the ranges' sizes, before any list is built)."""
    out: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        if not part:
            continue
        try:
            a, _, b = part.partition("-")
            lo, hi = int(a), int(b or a)
            if lo < 0 or hi < lo:
                raise ValueError
        except ValueError:
            raise ValueError(f"bad seed list {text!r}: use e.g. '0-4' or '0,1,2'") from None
        if len(out) + hi - lo + 1 > max_seeds:
            raise ValueError(f"seed list {text!r} asks for more than {max_seeds} seeds")
        out.extend(range(lo, hi + 1))
    if not out:
        raise ValueError(f"empty seed list {text!r}")
    return sorted(set(out))
