"""Per-env facts in one registry keyed by env id: :data:`ENV_INFO`.

Each :class:`EnvInfo` holds the env's benchmark metric (paper Table 4 / Table 16 key), its PARTIAL potential
template (paper Table 1 / Appendix D), the PARTIAL mass template of a configuration-dependent M(q) and the
paper's reported row (Tables 3, 17-24; mean, std over 5 seeds) when the paper has one.  Everything else is
derived from it: :func:`phast_model.train.metrics.benchmark_metric`, the templates of
:func:`phast_model.world.regimes.default_config` and the harness's :data:`phast_model.bench.paper.PAPER`.
Every paper number in the code base is typed here (with :data:`PAPER_FULL_STATE`, Table 25).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from phast_gym.systems import System


@dataclass(frozen=True)
class PaperRow:
    """One benchmark row: the metric key (paper Table 16 id) and per-model (mean, std), params."""

    benchmark: str
    metric: str
    table: str
    results: dict[str, tuple[float, float]]
    params: dict[str, int] = field(default_factory=dict)

    def best(self, prefix: str) -> tuple[str, float, float] | None:
        """(model, mean, std) of the lowest-mean model whose name starts (or not, prefix '!') with ``prefix``."""
        neg = prefix.startswith("!")
        pre = prefix.lstrip("!")
        rows = [(k, *v) for k, v in self.results.items() if k.startswith(pre) != neg]
        return min(rows, key=lambda r: r[1]) if rows else None


@dataclass(frozen=True)
class EnvInfo:
    """The facts of one env id (see the module docstring)."""

    env_id: str
    metric: str
    template: str | None = None  # PARTIAL potential template (None: not port-Hamiltonian)
    template_dims: tuple[int, ...] | None = None  # the template's angular dims (cosine); None: all
    mass_template: str | None = None  # PARTIAL mass template of a configuration-dependent M(q)
    paper: PaperRow | None = None
    #: PHASTConfig fields of this env's KNOWN default that differ from every env's (docs/phast_model.md)
    known: dict[str, Any] = field(default_factory=dict)

    def partial_mass_template(self, system: System) -> str | None:
        """The PARTIAL mass template of ``system`` (this env's physics, possibly with custom kwargs): None when M is
        constant; a double pendulum in ``coordinates="relative"`` takes ``"double_pendulum_relative"``."""
        if system.separable:
            return None
        if self.mass_template == "double_pendulum" and system.params.get("coordinates") == "relative":
            return "double_pendulum_relative"
        if self.mass_template is None:
            raise ValueError(f"no PARTIAL mass template for {self.env_id} ({system.name!r}, configuration-dependent M)")
        return self.mass_template


WRAP = "rollout_theta_wrap_mse_h100"
MIXED = "rollout_mixed_mse_h100"
ROLL = "rollout_mse_h100"
NEXT = "mse"

_P1 = {"phast-known": 3364, "phast-partial": 13736, "phast-unknown": 13738, "gru": 37889, "s5": 17089, "linoss": 17089,
       "dlinoss": 33793, "transformer": 100161, "vpt": 16833}
_P2 = {"phast-known": 3588, "phast-partial": 12166, "phast-unknown": 13067, "gru": 38146, "s5": 17218, "linoss": 17218,
       "dlinoss": 33922, "transformer": 100290, "vpt": 16962}
_PO = {**_P2, "phast-known": 3587, "phast-partial": 12165, "phast-unknown": 12171}


def _r(k: tuple, p: tuple, u: tuple, gru: tuple, s5: tuple, lin: tuple, dlin: tuple, tr: tuple, vpt: tuple) -> dict:
    return {"phast-known": k, "phast-partial": p, "phast-unknown": u, "gru": gru, "s5": s5, "linoss": lin,
            "dlinoss": dlin, "transformer": tr, "vpt": vpt}


def _nx(k: tuple, p: tuple, u: tuple, s5: tuple, lin: tuple, gru: tuple, lstm: tuple, vpt: tuple, tr: tuple) -> dict:
    return {"phast-known": k, "phast-partial": p, "phast-unknown": u, "s5": s5, "linoss": lin, "gru": gru,
            "lstm": lstm, "vpt": vpt, "transformer": tr}


def _env(env_id: str, metric: str, template: str | None = None, dims: tuple[int, ...] | None = None,
         mass: str | None = None, paper: tuple[str, str, dict, dict] | None = None,
         known: dict[str, Any] | None = None) -> EnvInfo:
    """``paper`` = (benchmark, table, results, params); its row metric is ``metric``."""
    row = PaperRow(paper[0], metric, *paper[1:]) if paper else None
    return EnvInfo(env_id, metric, template, dims, mass, row, dict(known or {}))


_ENTRIES: tuple[EnvInfo, ...] = (
    _env("PHAST/Pendulum-v0", WRAP, "cosine", (0,), paper=("Pendulum (cons)", "Table 17", _r(
        (0.738, 0.143), (0.680, 0.043), (0.993, 0.128), (2.939, 0.302), (2.941, 0.042), (2.849, 0.475), (2.738, 0.630),
        (2.320, 0.224), (2.875, 0.182)), _P1)),
    _env("PHAST/DampedPendulum-v0", WRAP, "cosine", (0,), paper=("Pendulum (damped)", "Table 17", _r(
        (0.017, 0.005), (0.018, 0.001), (0.275, 0.083), (1.310, 0.743), (0.657, 0.065), (2.286, 0.324), (0.450, 0.241),
        (0.493, 0.105), (2.111, 0.222)), _P1)),
    _env("PHAST/WindyPendulum-v0", WRAP, "cosine", (0,), paper=("Pendulum (windy)", "Table 17", _r(
        (0.106, 0.020), (0.092, 0.014), (0.298, 0.048), (1.796, 0.625), (0.600, 0.047), (1.458, 0.324), (0.435, 0.239),
        (0.824, 0.134), (2.218, 0.135)), _P1)),
    _env("PHAST/WindyCartPole-v0", MIXED, "cosine", (1,), mass="cartpole", paper=("Cart-Pole (windy)", "Table 3", {
        "phast-known": (0.063, 0.019), "phast-partial": (0.083, 0.022), "phast-unknown": (0.109, 0.022),
        "s5": (0.431, 0.077)},
        {"phast-known": 3589, "phast-partial": 14283, "phast-unknown": 14290, "s5": 17218}),
        # KNOWN: the loss from the central difference (the causal observer's velocity error biases D's cart entry)
        # and the damping floor d0 from the data's full floor (at 0.8 it stays under the cart's constant damping)
        known={"train_velocity": "central", "damping_floor_margin": 1.0}),
    _env("PHAST/Oscillator-v0", ROLL, "quadratic", paper=("Oscillator (cons)", "Table 19", _r(
        (0.0010, 0.0003), (0.0010, 0.0002), (0.0072, 0.0031), (1.8470, 0.0754), (2.0200, 0.0899), (1.7241, 0.1787),
        (1.8603, 0.2750), (1.0873, 0.2987), (3.0941, 1.1140)), _PO)),
    _env("PHAST/DampedOscillator-v0", ROLL, "quadratic", paper=("Oscillator (damped)", "Table 19", _r(
        (0.0012, 0.0004), (0.0011, 0.0003), (0.0101, 0.0046), (1.4565, 0.0811), (1.7079, 0.0570), (1.3927, 0.1189),
        (1.6275, 0.1809), (0.9259, 0.2537), (2.5710, 0.7990)), _PO)),
    _env("PHAST/DoublePendulum-v0", WRAP, "cosine", (0, 1), mass="double_pendulum", paper=("Double pendulum (cons)",
        "Table 18", _r((0.421, 0.061), (0.402, 0.047), (0.629, 0.060), (1.300, 0.143), (0.618, 0.028), (1.640, 0.214),
                       (1.501, 0.124), (1.033, 0.248), (2.848, 0.213)), _P2)),
    _env("PHAST/DampedDoublePendulum-v0", WRAP, "cosine", (0, 1), mass="double_pendulum", paper=(
        "Double pendulum (damped)", "Table 18",
        _r((0.332, 0.030), (0.320, 0.032), (0.529, 0.047), (1.346, 0.127), (0.630, 0.031), (1.573, 0.129),
           (1.298, 0.105), (0.846, 0.132), (2.721, 0.156)), _P2)),
    _env("PHAST/WindyDoublePendulum-v0", WRAP, "cosine", (0, 1), mass="double_pendulum"),  # not in the paper's Table 4
    _env("PHAST/RLCCircuit-v0", NEXT, "quadratic", paper=("RLC circuit (KNOWN)", "Table 20", _nx(
        (2.64e-5, 1.5e-8), (2.64e-5, 1.1e-8), (2.63e-5, 3.1e-8), (1.84e-3, 6.69e-4), (8.57e-4, 1.26e-4),
        (3.22e-3, 3.00e-4), (7.53e-3, 2.78e-4), (8.29e-4, 4.38e-5), (4.81e-4, 1.32e-4)),
        {"phast-known": 3364, "phast-partial": 11878, "phast-unknown": 11879, "s5": 17089, "linoss": 17089,
         "gru": 37889, "lstm": 50497, "vpt": 16833, "transformer": 100161})),
    _env("PHAST/LennardJones3-v0", NEXT, "lennard_jones", paper=("LJ-3 cluster (KNOWN)", "Table 21", _nx(
        (4.61e-10, 4.20e-12), (4.59e-10, 2.04e-12), (6.93e-10, 1.38e-11), (2.05e-4, 4.33e-5), (3.07e-4, 6.64e-5),
        (1.96e-3, 1.80e-4), (3.39e-3, 3.15e-4), (1.49e-3, 8.07e-4), (1.20e-3, 1.62e-4)),
        {"phast-known": 4490, "phast-partial": 13324, "phast-unknown": 13355, "s5": 17734, "linoss": 17734,
         "gru": 39174, "lstm": 52102, "vpt": 17478, "transformer": 100806})),
    _env("PHAST/HeatExchange-v0", NEXT, "quadratic", paper=("Heat exchange (KNOWN)", "Table 22", _nx(
        (2.42e-6, 9.74e-10), (2.42e-6, 2.63e-9), (2.48e-6, 1.85e-8), (1.00e-3, 1.62e-4), (4.46e-4, 3.11e-5),
        (3.63e-3, 3.31e-4), (8.03e-3, 1.39e-4), (1.71e-3, 1.53e-4), (7.74e-4, 2.14e-4)),
        {"phast-known": 3592, "phast-partial": 12170, "phast-unknown": 12173, "s5": 17218, "linoss": 17218,
         "gru": 38146, "lstm": 50818, "vpt": 16962, "transformer": 100290})),
    _env("PHAST/NBody3-v0", NEXT, "gravity", paper=("N-body gravity (PARTIAL)", "Table 23", _nx(
        (4.28e-8, 1.28e-11), (4.27e-8, 2.25e-11), (4.28e-8, 6.17e-11), (3.03e-3, 5.98e-4), (2.00e-3, 7.74e-5),
        (7.18e-3, 1.79e-3), (4.64e-2, 8.17e-3), (1.47e-2, 1.30e-2), (1.83e-3, 6.88e-4)),
        {"phast-known": 4489, "phast-partial": 13323, "phast-unknown": 13355, "s5": 17734, "linoss": 17734,
         "gru": 39174, "lstm": 52102, "vpt": 17478, "transformer": 100806})),
    # not port-Hamiltonian (a latent ODE, phast_model.world.regimes): no potential or mass template
    _env("PHAST/PredatorPrey-v0", NEXT, paper=("Predator-prey (UNKNOWN)", "Table 24", _nx(
        (0.0203, 0.0002), (0.0203, 0.0002), (0.0199, 0.0004), (6.12, 0.58), (3.53, 0.70), (4.72, 0.23), (5.85, 0.14),
        (0.226, 0.012), (0.179, 0.014)),
        {"phast-known": 3364, "phast-partial": 11878, "phast-unknown": 11879, "s5": 17089, "linoss": 17089,
         "gru": 37889, "lstm": 50497, "vpt": 16833, "transformer": 100161})),
)

#: env id -> its facts, in phast_gym.env_ids() order (the paper rows in Table 4 order)
ENV_INFO: dict[str, EnvInfo] = {info.env_id: info for info in _ENTRIES}

#: Table 25, full-state Windy Pendulum ((q, p) observed): wrapped rollout MSE at H = 100
PAPER_FULL_STATE = PaperRow("Pendulum (windy, full state)", WRAP, "Table 25", {
    "phast-partial": (0.089, 0.005), "phast-unknown": (0.128, 0.003), "dhnn": (2.264, 0.160)},
    {"phast-partial": 10376, "phast-unknown": 10378, "dhnn": 107124})
