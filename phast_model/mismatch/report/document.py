"""The mismatch report: the :class:`Report` data, its report.json view, its text (summary, markdown) and writing it.

``Report.write(out)`` writes report.json (docs/mismatch.md schema plus ``"tool": "phast-mismatch"``), report.md,
report.html (:mod:`.html`: self-contained, tables as HTML, plots embedded as data URIs) and the PNG plots
(:mod:`.plots`), through the safe writes of :mod:`.files`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.fileio import jsonable as _jsonable

from ..evaluate import FitTable
from ..rows import ParamRow, TermRow
from ..vocabulary.terms import AugmentedSystem
from .files import CURVE_PLOT, PLOTS, PLOTS_PREFIX, TOOL, write_atomically
from .html import data_uri, html_page
from .plots import plot


@dataclass(frozen=True)
class Report:
    """The report of docs/mismatch.md plus plot data.

    The calibrated parameters and the terms are typed rows; :meth:`to_dict` (the report.json schema) and the dict
    views :attr:`sim`, :attr:`missing_physics` and :attr:`details` convert them."""

    simulator: dict[str, Any]  # report.sim less the calibrated parameters: env_id, kwargs
    calibrated: dict[str, ParamRow]
    data: dict[str, Any]
    located: list[dict[str, Any]]
    terms: list[TermRow]  # the missing physics
    fit: dict[str, Any]
    summary: str
    diagnostics: dict[str, Any] = field(default_factory=dict)  # report.details less the unconfirmed terms
    unconfirmed: list[TermRow] = field(default_factory=list)  # terms that do not improve the held-out prediction
    plot_data: dict[str, Any] = field(default_factory=dict, repr=False)
    files: dict[str, str] = field(default_factory=dict, repr=False)  # more files of the report folder (calibrated.xml)

    @property
    def sim(self) -> dict[str, Any]:
        """report.sim: the simulator and its calibrated parameters."""
        return {**self.simulator, "calibrated": {k: row.to_dict() for k, row in self.calibrated.items()}}

    @property
    def missing_physics(self) -> list[dict[str, Any]]:
        """report.missing_physics."""
        return [m.to_dict() for m in self.terms]

    @property
    def details(self) -> dict[str, Any]:
        """report.details."""
        return {**self.diagnostics, "unconfirmed_terms": [m.to_dict() for m in self.unconfirmed]}

    def to_dict(self) -> dict[str, Any]:
        return {"sim": self.sim, "data": self.data, "located": self.located, "missing_physics": self.missing_physics,
                "fit": self.fit, "summary": self.summary, "details": self.details}

    def augmented_system(self) -> AugmentedSystem:
        """The augmented simulator (calibrated kwargs + found terms)."""
        return self.plot_data["augmented_system"]

    def write(self, out_dir: str | Path, plots: bool = True) -> Path:
        """report.json, report.md, report.html and PNG plots into ``out_dir`` (atomically; see :func:`write_report`)."""
        return write_report(self, out_dir, plots=plots)


# --------------------------------------------------------------------------- summary
def _fitted_note(row: ParamRow) -> str:
    """The table's note of a fitted value: how much of it the recordings decide, where a prior entered."""
    if row.data_share is None:
        return "fitted"
    return f"fitted; {row.data_share:.0%} from the recordings, the rest the file's prior"


def _fmt_ci(ci: Sequence[float] | None) -> str:
    return "" if not ci else f" [95% CI {ci[0]:.4g}, {ci[1]:.4g}]"


def _energy_check_sentence(fitres: FitTable) -> str | None:
    """The held-out energy check, when the held-out recordings lose clearly more (or less) energy than predicted."""
    ec = fitres.energy_check or {}
    tr, ho = ec.get("training"), ec.get("held_out")
    if ho is None:
        return None
    r, (lo, hi) = ho["measured_over_predicted"], ho["ci95"]
    rt = tr["measured_over_predicted"] if tr is not None else 1.0
    if (lo > 1.0 or hi < 1.0) and abs(r - 1.0) > 0.1 and abs(rt - 1.0) < 0.5 * abs(r - 1.0):
        return (f"Held-out check: the recordings not used for fitting lose {r:.3g}x [95% CI {lo:.3g}, {hi:.3g}] the "
                f"energy the augmented model dissipates (training recordings: {rt:.3g}x), so the dissipation law found "
                "on the training recordings does not carry over to them: it changes with amplitude, time or conditions "
                "in a way the vocabulary does not describe.")
    return None


def _alternative_sentences(missing: Sequence[TermRow]) -> list[str]:
    """Terms the data cannot tell apart (shooting), and friction laws nearly as predictive (weak form), said once
    each."""
    out, laws_said = [], set()
    for m in missing:
        terms = [a.name for a in m.alternatives if a.law is None]
        if terms:
            out.append(f"The data cannot tell {m.term} apart from: {', '.join(terms)}.")
        laws = [a.law for a in m.alternatives if a.law is not None]
        if laws and m.coordinate not in laws_said:
            laws_said.add(m.coordinate)
            out.append(f"On coordinate {m.coordinate}, these friction laws predict the left-out recordings' friction "
                       f"curves nearly as well: {'; '.join(laws)}.")
    return out


def summary_text(name: str, calibrated: Mapping[str, ParamRow], missing: Sequence[TermRow], located: list[dict],
                 fitres: FitTable,
                 chi2_calibrated: float, chi2_augmented: float, sigma: np.ndarray, verdicts: Sequence[str] = ()) -> str:
    """The report's plain-language summary (the chi^2/dof of the calibrated and augmented shooting fits decide what is
    said)."""
    parts = [f"Compared {name} with the recordings (estimated measurement noise "
             f"{float(np.sqrt(np.mean(sigma**2))):.3g})."]
    cal = [f"{k} {v.nominal:.4g} -> {v.fitted:.4g}{_fmt_ci(v.ci95)}" for k, v in calibrated.items() if v.from_data]
    if cal:
        parts.append("Calibrated parameters: " + "; ".join(cal) + ".")
    prior = sum(v.changed and not v.from_data for v in calibrated.values())
    if prior:
        parts.append(f"{prior} more value(s) refitted within the file's prior, each consistent with the file's value "
                     "or mostly decided by the prior (the table).")
    # the simulator does not describe the recordings / found terms do not predict: nothing is named
    parts += list(verdicts)
    if missing:
        items = [f"{m.term} on coordinate {m.coordinate} ({m.component}), coefficient "
                 f"{m.coefficient:.4g}{_fmt_ci(m.ci95)}"
                 for m in missing]
        parts.append("Missing physics: " + "; ".join(items) + ".")
        neg = [m.label for m in missing if m.component == "dissipation" and m.coefficient < 0]
        if neg:
            parts.append(f"Negative coefficient(s) {', '.join(neg)}: they lower the model's own dissipation, and the "
                         "total friction force stays passive (opposes motion) at every speed the recordings reach.")
        parts += _alternative_sentences(missing)
    elif chi2_calibrated < 1.5 and not verdicts:
        parts.append("No missing physics: the calibrated simulator agrees with the recordings within the noise.")
    if located and chi2_augmented >= 1.5 and not any("does not describe" in v for v in verdicts):
        loc = located[0]
        parts.append("Incomplete: the final model's residual on the training recordings is "
                     f"{math.sqrt(chi2_augmented):.3g} "
                     f"times the noise. Unexplained residual, located at coordinate {loc['coordinate']} "
                     f"({loc['component']}), "
                     f"where {loc['where']}, {loc['when']}; no term of the vocabulary explains it.")
    b, c, a = fitres.rmse("nominal"), fitres.rmse("calibrated"), fitres.rmse("augmented")
    parts.append(f"On {fitres.evaluated_on}: rollout RMSE nominal {b:.4g}, calibrated {c:.4g}, augmented {a:.4g}.")
    sentence = _energy_check_sentence(fitres)
    if sentence:
        parts.append(sentence)
    return " ".join(parts)


# --------------------------------------------------------------------------- markdown
def markdown(report: Report) -> str:
    """A human-readable version of the report."""
    d = report.to_dict()
    lines = [f"# Mismatch report: {d['sim']['env_id']}", "", d["summary"], "",
             f"Data: {d['data']['n_traj']} recordings x {d['data']['T']} samples, dt = {d['data']['dt']}, "
             f"estimated noise std {d['data']['noise_std']:.3g} ({d['data']['source']}).", "",
             *([f"Logs: {d['data']['logs']['note']}.", ""] if "logs" in d["data"] else []),
             "## Calibrated parameters", "",
             "| parameter | nominal | fitted | 95% CI | note |", "|---|---|---|---|---|"]
    for k, v in report.calibrated.items():
        ci_s = f"[{v.ci95[0]:.4g}, {v.ci95[1]:.4g}]" if v.ci95 else "-"
        lines.append(f"| {k} | {v.nominal:.4g} | {v.fitted:.4g} | {ci_s} | {v.note or _fitted_note(v)} |")
    lines += ["", "## Where the mismatch is (calibrated model, training recordings)", ""]
    if d["located"]:
        lines += ["| coordinate | component | where | when | share |", "|---|---|---|---|---|"]
        for loc in d["located"]:
            lines.append(f"| {loc['coordinate']} | {loc['component']} | {loc['where']} | {loc['when']} | "
                         f"{loc['share']:.2f} |")
    else:
        lines.append("Nothing beyond the noise.")
    lines += ["", "## Missing physics", ""]
    if report.terms:
        lines += ["| term | coordinate | component | coefficient | 95% CI | expression | explains | alternatives |",
                  "|---|---|---|---|---|---|---|---|"]
        for m in report.terms:
            alts = ", ".join(a.name for a in m.alternatives) or "-"
            expl = "-" if m.explains is None else format(m.explains, ".2f")
            lines.append(f"| {m.term} | {m.coordinate} | {m.component} | {m.coefficient:.4g} | "
                         f"[{m.ci95[0]:.4g}, {m.ci95[1]:.4g}] | `{m.expression}` | {expl} | {alts} |")
    else:
        lines.append("None found.")
    f = d["fit"]
    lines += ["", f"## Fit on {f['evaluated_on']}", "", "| model | one-step MSE | rollout RMSE |", "|---|---|---|"]
    # ours, then any compared models
    for name in [k for k, v in f.items() if isinstance(v, dict) and "rollout_rmse" in v]:
        lines.append(f"| {name} | {f[name]['one_step_mse']:.4g} | {f[name]['rollout_rmse']:.4g} |")
    lines += ["", f"Rollout: {f.get('rollout', '')}", ""]
    ec = f.get("energy_check") or {}
    if any(ec.get(k) for k in ("training", "held_out")):
        lines += ["Energy check (measured energy loss / energy the augmented model dissipates, per half-cycle between "
                  "turning points; 1 = the found dissipation accounts for all of it):", "",
                  "| recordings | measured / predicted | 95% CI | per recording |", "|---|---|---|---|"]
        for k in ("training", "held_out"):
            e = ec.get(k)
            if e:
                per = ", ".join("-" if x is None else f"{x:.3g}" for x in e["per_recording"])
                lo, hi = e["ci95"]
                lines.append(f"| {k.replace('_', '-')} | {e['measured_over_predicted']:.3g} | [{lo:.3g}, {hi:.3g}] | "
                             f"{per} |")
        lines.append("")
    lines += _friction_lines(d["details"].get("friction") or {})
    plots = list(PLOTS) + ([CURVE_PLOT] if report.plot_data.get("friction_curve") is not None else [])
    lines += [PLOTS_PREFIX + ", ".join(plots), "",
              "## Method", "", str(d["details"].get("method", "")), ""]
    if d["details"].get("intervals"):
        lines += [f"95% intervals: {d['details']['intervals']}.", ""]
    return "\n".join(lines)




def _friction_lines(fr: dict[str, Any]) -> list[str]:
    """The friction section: the curve from the training recordings, the chosen law band by band, passivity."""
    if not fr.get("used"):
        return []
    law, passive = fr["law"], fr["passivity"]
    lines = ["## Friction from the training recordings", "",
             f"Chosen law: **{law['law']}** ({fr['selection'][0]['folds']}; score: how well a law fitted on the other "
             "recordings predicts the left-out recording's friction curve). Total friction force passive at every "
             f"observed speed: {'yes' if passive['passive'] else 'NO'}"
             + "".join(f"; coordinate {p['coordinate']} has negative {', '.join(p['negative_terms'])} (the total stays "
                       "passive)"
                       for p in passive["per_coordinate"] if p["negative_terms"] and p["passive"]) + ".", "",
             "Non-parametric friction curve (total dissipative force opposing motion, mean per speed band with a "
             "block-bootstrap 95% interval) and the chosen law through the same filter:", "",
             "| coordinate | \\|qdot\\| band | curve | 95% CI | law | inside |", "|---|---|---|---|---|---|"]
    for r in fr["law_vs_curve"]:
        if r["direction"] != "both":
            continue
        lines.append(f"| {r['coordinate']} | {r['band'][0]:.3g}-{r['band'][1]:.3g} | {r['curve']:.4g} | "
                     f"[{r['ci95'][0]:.4g}, {r['ci95'][1]:.4g}] | {r['law']:.4g} | {'yes' if r['inside'] else 'no'} |")
    return lines + [""]


# --------------------------------------------------------------------------- writing
def _write_files(report: Report, plots: bool, tmp: Path) -> None:
    (tmp / "report.json").write_text(json.dumps(_jsonable({"tool": TOOL, **report.to_dict()}), indent=2) + "\n")
    text = markdown(report)
    (tmp / "report.md").write_text(text)
    smoothing = int(report.details.get("smoothing_window_samples", 7))
    images = {name: data_uri(tmp / name) for name in plot(report.plot_data, smoothing, tmp)} if plots else {}
    (tmp / "report.html").write_text(html_page(report.simulator.get("env_id", ""), text, images))
    for name, content in report.files.items():
        (tmp / name).write_text(content)


def write_report(report: Report, out_dir: str | Path, plots: bool = True) -> Path:
    """report.json, report.md, report.html, the PNG plots (``plots``) and the report's other files into ``out_dir``,
    written into a temporary sibling directory and then swapped in (:func:`.files.write_atomically`)."""
    return write_atomically(out_dir, partial(_write_files, report, plots))
