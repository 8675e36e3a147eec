"""The mismatch report: the :class:`Report` data, its text (summary, markdown, HTML), plots, and writing it safely.

``Report.write(out)`` writes report.json (docs/mismatch.md schema plus ``"tool":
"phast-mismatch"``), report.md, report.html (self-contained: tables as HTML,
plots embedded as data URIs) and the PNG plots.  It never deletes what it did
not write: ``out`` must be new, empty, or a previous phast-mismatch report
(recognised by that marker and by holding nothing but report files), which is
then replaced atomically.
"""

from __future__ import annotations

import base64
import html as _html
import json
import os
import re
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.fileio import jsonable as _jsonable
from phast_gym.systems import break_at_wraps, wrap

from .evaluate import FitTable
from .rows import ParamRow, TermRow
from .terms import AugmentedSystem

#: report.json's marker of a directory this tool wrote
TOOL = "phast-mismatch"
PLOTS = ("residual_map.png", "heldout_fit.png", "decay.png")
#: written when the report carries a friction curve
CURVE_PLOT = "friction_curve.png"
#: the user's MuJoCo model with the calibrated parameters and the found terms it can express (MJCF / URDF simulators)
CALIBRATED_MODEL = "calibrated.xml"
#: every file a report directory holds (nothing else may be there for it to be replaced)
REPORT_FILES = ("report.json", "report.md", "report.html") + PLOTS + (CURVE_PLOT, "error.log", CALIBRATED_MODEL)
PLOTS_PREFIX = "Plots: "
_MODELS = (("nominal", ":"), ("calibrated", "--"), ("augmented", "-"))


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
        return (f"Held-out check: the recordings not used for fitting lose {r:.3g}x [95% CI {lo:.3g}, {hi:.3g}] the energy the "
                f"augmented model dissipates (training recordings: {rt:.3g}x), so the dissipation law found on the training "
                "recordings does not carry over to them: it changes with amplitude, time or conditions in a way the "
                "vocabulary does not describe.")
    return None


def _alternative_sentences(missing: Sequence[TermRow]) -> list[str]:
    """Terms the data cannot tell apart (shooting), and friction laws nearly as predictive (weak form), said once each."""
    out, laws_said = [], set()
    for m in missing:
        terms = [a.name for a in m.alternatives if a.law is None]
        if terms:
            out.append(f"The data cannot tell {m.term} apart from: {', '.join(terms)}.")
        laws = [a.law for a in m.alternatives if a.law is not None]
        if laws and m.coordinate not in laws_said:
            laws_said.add(m.coordinate)
            out.append(f"On coordinate {m.coordinate}, these friction laws predict the left-out recordings' friction curves "
                       f"nearly as well: {'; '.join(laws)}.")
    return out


def summary_text(name: str, calibrated: Mapping[str, ParamRow], missing: Sequence[TermRow], located: list[dict], fitres: FitTable,
                 chi2_calibrated: float, chi2_augmented: float, sigma: np.ndarray, verdicts: Sequence[str] = ()) -> str:
    """The report's plain-language summary (the chi^2/dof of the calibrated and augmented shooting fits decide what is said)."""
    parts = [f"Compared {name} with the recordings (estimated measurement noise {float(np.sqrt(np.mean(sigma**2))):.3g})."]
    cal = [f"{k} {v.nominal:.4g} -> {v.fitted:.4g}{_fmt_ci(v.ci95)}" for k, v in calibrated.items() if v.ci95]
    if cal:
        parts.append("Calibrated parameters: " + "; ".join(cal) + ".")
    parts += list(verdicts)  # the simulator does not describe the recordings / found terms do not predict: nothing is named
    if missing:
        items = [f"{m.term} on coordinate {m.coordinate} ({m.component}), coefficient {m.coefficient:.4g}{_fmt_ci(m.ci95)}"
                 for m in missing]
        parts.append("Missing physics: " + "; ".join(items) + ".")
        neg = [m.label for m in missing if m.component == "dissipation" and m.coefficient < 0]
        if neg:
            parts.append(f"Negative coefficient(s) {', '.join(neg)}: they lower the model's own dissipation, and the total friction "
                         "force stays passive (opposes motion) at every speed the recordings reach.")
        parts += _alternative_sentences(missing)
    elif chi2_calibrated < 1.5 and not verdicts:
        parts.append("No missing physics: the calibrated simulator agrees with the recordings within the noise.")
    if located and chi2_augmented >= 1.5 and not any("does not describe" in v for v in verdicts):
        loc = located[0]
        parts.append(f"Unexplained residual, located at coordinate {loc['coordinate']} ({loc['component']}), where {loc['where']}, "
                     f"{loc['when']}; no term of the vocabulary explains it.")
    b, c, a = fitres.rmse("nominal"), fitres.rmse("calibrated"), fitres.rmse("augmented")
    parts.append(f"On {fitres.evaluated_on}: rollout RMSE nominal {b:.4g}, calibrated {c:.4g}, augmented {a:.4g}.")
    sentence = _energy_check_sentence(fitres)
    if sentence:
        parts.append(sentence)
    return " ".join(parts)


# --------------------------------------------------------------------------- markdown and HTML
def markdown(report: Report) -> str:
    """A human-readable version of the report."""
    d = report.to_dict()
    lines = [f"# Mismatch report: {d['sim']['env_id']}", "", d["summary"], "",
             f"Data: {d['data']['n_traj']} recordings x {d['data']['T']} samples, dt = {d['data']['dt']}, "
             f"estimated noise std {d['data']['noise_std']:.3g} ({d['data']['source']}).", "", "## Calibrated parameters", "",
             "| parameter | nominal | fitted | 95% CI | note |", "|---|---|---|---|---|"]
    for k, v in report.calibrated.items():
        ci_s = f"[{v.ci95[0]:.4g}, {v.ci95[1]:.4g}]" if v.ci95 else "-"
        lines.append(f"| {k} | {v.nominal:.4g} | {v.fitted:.4g} | {ci_s} | {v.note or 'fitted'} |")
    lines += ["", "## Where the mismatch is (calibrated model, training recordings)", ""]
    if d["located"]:
        lines += ["| coordinate | component | where | when | share |", "|---|---|---|---|---|"]
        for loc in d["located"]:
            lines.append(f"| {loc['coordinate']} | {loc['component']} | {loc['where']} | {loc['when']} | {loc['share']:.2f} |")
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
    for name in [k for k, v in f.items() if isinstance(v, dict) and "rollout_rmse" in v]:  # ours, then any compared models
        lines.append(f"| {name} | {f[name]['one_step_mse']:.4g} | {f[name]['rollout_rmse']:.4g} |")
    lines += ["", f"Rollout: {f.get('rollout', '')}", ""]
    ec = f.get("energy_check") or {}
    if any(ec.get(k) for k in ("training", "held_out")):
        lines += ["Energy check (measured energy loss / energy the augmented model dissipates, per half-cycle between turning "
                  "points; 1 = the found dissipation accounts for all of it):", "",
                  "| recordings | measured / predicted | 95% CI | per recording |", "|---|---|---|---|"]
        for k in ("training", "held_out"):
            e = ec.get(k)
            if e:
                per = ", ".join("-" if x is None else f"{x:.3g}" for x in e["per_recording"])
                lo, hi = e["ci95"]
                lines.append(f"| {k.replace('_', '-')} | {e['measured_over_predicted']:.3g} | [{lo:.3g}, {hi:.3g}] | {per} |")
        lines.append("")
    lines += _friction_lines(d["details"].get("friction") or {})
    plots = list(PLOTS) + ([CURVE_PLOT] if report.plot_data.get("friction_curve") is not None else [])
    lines += [PLOTS_PREFIX + ", ".join(plots), "",
              "## Method", "", str(d["details"].get("method", "")), ""]
    return "\n".join(lines)




def _friction_lines(fr: dict[str, Any]) -> list[str]:
    """The friction section: the curve from the training recordings, the chosen law band by band, passivity."""
    if not fr.get("used"):
        return []
    law, passive = fr["law"], fr["passivity"]
    lines = ["## Friction from the training recordings", "",
             f"Chosen law: **{law['law']}** ({fr['selection'][0]['folds']}; score: how well a law fitted on the other recordings "
             "predicts the left-out recording's friction curve). Total friction force passive at every observed speed: "
             f"{'yes' if passive['passive'] else 'NO'}"
             + "".join(f"; coordinate {p['coordinate']} has negative {', '.join(p['negative_terms'])} (the total stays passive)"
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


_INLINE_CODE = re.compile(r"`([^`]*)`")


def _inline(text: str) -> str:
    """Escaped text with `code` spans."""
    return _INLINE_CODE.sub(lambda m: f"<code>{m.group(1)}</code>", _html.escape(text, quote=False))


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _is_rule(line: str) -> bool:
    """A table's header rule: only |, -, : and spaces."""
    return "-" in line and not line.strip().strip("|-: ")


def _table(rows: list[str]) -> str:
    """A markdown pipe table (header, ``|---|`` rule, body) as an HTML table."""
    head, body = rows[0], rows[2:] if len(rows) > 1 and _is_rule(rows[1]) else rows[1:]
    out = ["<table>", "<thead><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in _cells(head)) + "</tr></thead>", "<tbody>"]
    out += ["<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in _cells(r)) + "</tr>" for r in body]
    return "\n".join(out + ["</tbody>", "</table>"])


def _figures(images: dict[str, str]) -> str:
    return "\n".join(f'<figure><img alt="{name}" src="{uri}"><figcaption>{name}</figcaption></figure>' for name, uri in images.items())


def markdown_to_html(text: str, images: dict[str, str] | None = None) -> str:
    """The subset of markdown :func:`markdown` writes (# / ## headings, pipe tables, paragraphs, `code`) as HTML body
    elements; the ``Plots:`` paragraph becomes the embedded ``images`` (name -> data URI) when given."""
    blocks: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            i += 1
        elif line.startswith("#"):
            level = min(len(line) - len(line.lstrip("#")), 6)
            blocks.append(f"<h{level}>{_inline(line[level:].strip())}</h{level}>")
            i += 1
        elif line.lstrip().startswith("|"):
            j = i
            while j < len(lines) and lines[j].lstrip().startswith("|"):
                j += 1
            blocks.append(_table(lines[i:j]))
            i = j
        else:
            j = i
            while j < len(lines) and lines[j].strip() and not lines[j].startswith("#") and not lines[j].lstrip().startswith("|"):
                j += 1
            para = " ".join(s.strip() for s in lines[i:j])
            blocks.append(_figures(images) if images and para.startswith(PLOTS_PREFIX) else f"<p>{_inline(para)}</p>")
            i = j
    return "\n".join(blocks)


_CSS = ("body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;line-height:1.45}"
        "table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #bbb;padding:.25em .6em;text-align:left}"
        "th{background:#eee}code{background:#f4f4f4;padding:0 .2em}figure{margin:1em 0}img{max-width:100%}")


def html_page(report: Report, images: dict[str, str] | None = None) -> str:
    """report.html: one self-contained page (no external resources)."""
    title = _html.escape(f"Mismatch report: {report.simulator.get('env_id', '')}")
    return (f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{title}</title>\n"
            f"<style>{_CSS}</style>\n</head>\n<body>\n{markdown_to_html(markdown(report), images)}\n</body>\n</html>\n")


def _data_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


# --------------------------------------------------------------------------- plots
def _residual_map(plt: Any, report: Report, out: Path) -> None:
    """residual_map.png: the calibrated model's residual force over (q_i, qdot_i), per coordinate."""
    pd = report.plot_data
    rm = pd["resid_map"]
    n = rm["r"].shape[-1]
    fig, axes = plt.subplots(1, n, figsize=(5 * n, 4), squeeze=False)
    for i in range(n):
        ax = axes[0, i]
        q, v, r = rm["q"][..., i].reshape(-1), rm["v"][..., i].reshape(-1), rm["r"][..., i].reshape(-1)
        if i in pd["train"].angle_dims:
            q = wrap(q)
        H, xe, ye = np.histogram2d(q, v, bins=40, weights=r)
        C, _, _ = np.histogram2d(q, v, bins=[xe, ye])
        M = np.where(C > 0, H / np.maximum(C, 1), np.nan)
        lim = np.nanpercentile(np.abs(M), 98) if np.any(np.isfinite(M)) else 1.0
        im = ax.imshow(M.T, origin="lower", aspect="auto", extent=[xe[0], xe[-1], ye[0], ye[-1]], cmap="RdBu_r", vmin=-lim, vmax=lim)
        fig.colorbar(im, ax=ax, label="residual force (pdot units)")
        ax.set_xlabel(f"q{i}")
        ax.set_ylabel(f"qdot{i}")
        ax.set_title(f"calibrated-model residual, coordinate {i}")
    fig.tight_layout()
    fig.savefig(out / "residual_map.png", dpi=90)
    plt.close(fig)


def _heldout_fit(plt: Any, report: Report, out: Path) -> None:
    """heldout_fit.png: the first held-out recording and the three models' rollouts, with their errors."""
    hold, roll = report.plot_data["hold"], report.plot_data["rollouts"]
    n = hold.n
    t = np.arange(hold.T) * hold.dt
    fig, axes = plt.subplots(2, n, figsize=(6 * n, 6), squeeze=False, sharex=True)
    for i in range(n):
        ax = axes[0, i]
        ax.plot(t, hold.q[0, :, i], "k.", ms=2, label="measured")
        for name, style in _MODELS:
            ax.plot(t, roll[name][0, :, i], style, lw=1, label=name)
        ax.set_ylabel(f"q{i}")
        ax.set_title(f"held-out recording 0, coordinate {i}")
        ax.legend(fontsize=7)
        ax = axes[1, i]
        for name, style in _MODELS:
            e = roll[name][0, :, i] - hold.q[0, :, i]
            if i in hold.angle_dims:
                e = break_at_wraps(wrap(e))
            ax.plot(t, e, style, lw=1, label=name)
        ax.set_ylabel("error")
        ax.set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(out / "heldout_fit.png", dpi=90)
    plt.close(fig)


def _decay(plt: Any, report: Report, out: Path) -> None:
    """decay.png: energy of the calibrated H along the smoothed held-out states vs along the models' rollouts."""
    from ..rigs.shooting import momentum, smooth

    pd = report.plot_data
    hold, roll, sysC = pd["hold"], pd["rollouts"], pd["calibrated_system"]
    n = hold.n
    t = np.arange(hold.T) * hold.dt
    w = min(int(report.details.get("smoothing_window_samples", 7)), hold.T - 1 - (hold.T % 2 == 0))
    qs, vs = smooth(hold.q, hold.dt, max(w, 5))

    def energy(q: np.ndarray, v: np.ndarray) -> np.ndarray:
        p = momentum(sysC, q, v)
        return np.asarray(sysC.base.hamiltonian(tuple(q[..., i] for i in range(n)), tuple(p[..., i] for i in range(n))))

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(t, energy(qs, vs).mean(0), "k", lw=2, label="measured (smoothed)")
    for name, style in _MODELS:
        qr = roll[name]
        vr = np.gradient(qr, hold.dt, axis=1)
        ax.plot(t, energy(qr, vr).mean(0), style, label=name)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("mean energy H (calibrated)")
    ax.set_title("energy decay, held-out recordings")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "decay.png", dpi=90)
    plt.close(fig)


def plot(report: Report, out: Path) -> list[str]:
    """residual_map.png, heldout_fit.png and decay.png into ``out``; returns the names written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _residual_map(plt, report, out)
    _heldout_fit(plt, report, out)
    _decay(plt, report, out)
    curve = report.plot_data.get("friction_curve")
    if curve is None:
        return list(PLOTS)
    from .friction import plot_friction_curve

    plot_friction_curve(curve, report.plot_data.get("friction_laws"), str(out / CURVE_PLOT))
    return [*PLOTS, CURVE_PLOT]


# --------------------------------------------------------------------------- writing
def is_report_dir(path: Path) -> bool:
    """A directory this tool wrote: report.json with ``"tool": "phast-mismatch"`` and only report files."""
    entries = list(path.iterdir())
    if not all(p.name in REPORT_FILES and p.is_file() and not p.is_symlink() for p in entries):
        return False
    if [p.name for p in entries] == ["error.log"]:  # what a failed run left: its traceback only
        return True
    if not (path / "report.json").is_file():
        return False
    try:
        d = json.loads((path / "report.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(d, dict) and d.get("tool") == TOOL


def _check_replaceable(out: Path) -> None:
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise ValueError(f"refusing to overwrite {out}: it exists and is not a directory (give a new or report directory as --out)")
    if out.is_dir() and any(out.iterdir()) and not is_report_dir(out):
        raise ValueError(f"refusing to overwrite {out}: it is a non-empty directory that is not a phast-mismatch report "
                         f"(a report directory holds only {', '.join(REPORT_FILES)}); give a new or empty directory")


def check_writable(out_dir: str | Path) -> Path:
    """Fail fast (before any analysis) when the report could not be written to ``out_dir``: it is a file, a non-empty
    directory other than a previous report, or its nearest existing ancestor is not a writable directory."""
    out = Path(out_dir)
    _check_replaceable(out)
    parent = out.absolute().parent
    while not parent.exists() and not parent.is_symlink() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"cannot write the report to {out}: {parent} is not a directory")
    try:  # os.access is not enough (root, read-only mounts): create and remove a probe directory
        os.rmdir(tempfile.mkdtemp(prefix=f".{out.name}.probe-", dir=parent))
    except OSError as exc:
        raise ValueError(f"cannot write the report to {out}: {parent} is not writable ({exc.strerror or exc})") from None
    return out


def _write_files(report: Report, tmp: Path, plots: bool) -> None:
    (tmp / "report.json").write_text(json.dumps(_jsonable({"tool": TOOL, **report.to_dict()}), indent=2) + "\n")
    (tmp / "report.md").write_text(markdown(report))
    images = {name: _data_uri(tmp / name) for name in plot(report, tmp)} if plots else {}
    (tmp / "report.html").write_text(html_page(report, images))
    for name, text in report.files.items():
        (tmp / name).write_text(text)


def _swap(tmp: Path, out: Path) -> None:
    """Move ``tmp`` to ``out``; a previous report there is moved aside first and then only its own files are removed."""
    _check_replaceable(out)
    if not out.exists():
        os.replace(tmp, out)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
    os.rmdir(old)
    os.replace(out, old)
    try:
        os.replace(tmp, out)
    except BaseException:
        os.replace(old, out)
        raise
    for name in REPORT_FILES:
        (old / name).unlink(missing_ok=True)
    try:
        old.rmdir()
    except OSError:  # something else appeared in it meanwhile: leave it
        pass


def write_report(report: Report, out_dir: str | Path, plots: bool = True) -> Path:
    """Write into a temporary sibling directory, then swap it in: no half-written report is ever left, and nothing the
    tool did not write is deleted (see :func:`check_writable`)."""
    out = check_writable(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp creates 0700; a report directory is an ordinary one
    try:
        _write_files(report, tmp, plots)
        _swap(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
