"""The run report as a page: its sections (text, tables, figures) and one self-contained HTML file.

Sections, in the order a reader needs them:

0. verdict          healthy, degraded or flagged; the one-line reason; mean and max TCP error
                    against the baseline; the top missing effect, if any (the first screen)
1. summary          robot, run, plan hash, cell, calibration, software; the fit's lines
2. plan coverage    commanded joint angles over each joint's range and the TCP positions
                    (paper Fig. 6)
3. workspace error  histogram of the model's TCP error over the whole workspace (Fig. 7)
4. error curves     each joint's six error motions with 95 % bands (Fig. 8)
5. residuals        measured minus model, per pose and against each joint angle
6. diagnosis        which physical effect the model misses, if any
7. trend            the robot's figures over time against its baseline, control limits,
                    root-cause hints (when the run is archived)
8. ISO 9283         pose accuracy AP and repeatability RP at plan poses visited repeatedly:
                    position and, for pose (7D) data, orientation (a, b, c about the base axes)

Each ``*_section`` function turns what the report found (SI, typed: the fitted model, the
workspace error, the trend, the :class:`~quickhealth.station.reporting.verdict.Judgement`…) into a
:class:`Section` in the units people read (mm, degrees, mrad); :func:`render_html` turns the
sections into the page.  Gathering the findings from a run folder is the report service's job
(:func:`quickhealth.station.services.report.build_report`).  :meth:`Report.to_dict` is the
page's content as JSON (also embedded in the page as
``<script type="application/json" id="report-json">``).  A section whose input is missing says
what is missing and how to get it ("Not available: ..."), never a silent gap; a section that
does not apply to the run (ISO 9283 on a plan without repeated poses) says why ("Not
applicable: ...").  ``plots=False`` leaves the figures out (report.json alone needs none).
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from ...identify.errormodel import MOTION_WORDS, MOTIONS  # noqa: E402
from ...identify.fit import FittedModel  # noqa: E402
from ...identify.measurements import Measurements  # noqa: E402
from ...identify.report import residual_plot, workspace_histogram  # noqa: E402
from ...identify.robot import RobotModel, nominal_of  # noqa: E402
from ...identify.trend import TrendResult  # noqa: E402
from ...identify.workspace import JointCurves, WorkspaceError  # noqa: E402
from ..formats.common import json_plain as _plain  # noqa: E402
from ..formats.report import trend_to_json  # noqa: E402
from .iso9283 import PoseStats  # noqa: E402
from .verdict import HealthVerdict, Judgement  # noqa: E402

F = NDArray[np.float64]


@dataclass(frozen=True)
class Plot:
    """One embedded figure."""

    key: str
    title: str
    png: bytes


@dataclass(frozen=True)
class Section:
    """One part of the report: text lines, a table, figures, or why it is missing."""

    key: str
    title: str
    lines: tuple[str, ...] = ()
    table: tuple[tuple[str, ...], ...] = ()  # first row = header
    plots: tuple[Plot, ...] = ()
    missing: str = ""  # non-empty: the section could not be made, and why
    # non-empty: the section does not apply to this run (nothing is missing), and why
    not_applicable: str = ""
    data: dict[str, Any] = field(default_factory=dict)
    folded: tuple[tuple[str, ...], ...] = ()  # a second table, folded away (same header)
    folded_title: str = ""

    def to_dict(self) -> dict[str, Any]:
        """The section as JSON-able data (its numbers and text; figures by key)."""
        return {
            "title": self.title,
            "lines": list(self.lines),
            "table": [list(r) for r in self.table],
            "plots": [p.key for p in self.plots],
            "missing": self.missing or None,
            "not_applicable": self.not_applicable or None,
            "data": self.data,
            "folded": [list(r) for r in self.folded],
        }


@dataclass(frozen=True)
class Report:
    """The whole report of one run."""

    title: str
    run_dir: str
    sections: tuple[Section, ...]

    @property
    def plots(self) -> list[Plot]:
        """Every figure, in page order."""
        return [p for s in self.sections for p in s.plots]

    def section(self, key: str) -> Section:
        """The section ``key`` (``"verdict"``, ``"trend"`` …)."""
        return next(s for s in self.sections if s.key == key)

    def to_dict(self) -> dict[str, Any]:
        """The report's content as JSON-able data (sections with their numbers and text)."""
        return {
            "title": self.title,
            "run_dir": self.run_dir,
            "sections": {s.key: s.to_dict() for s in self.sections},
        }


# ------------------------------------------------------------------------ figures


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return buf.getvalue()


def _coverage_figure(robot: RobotModel, q: F, q_lo: F, q_hi: F) -> Figure:
    nj = q.shape[1]
    fig = Figure(figsize=(10.0, 5.6))
    for j in range(nj):
        ax = fig.add_subplot(2, nj, j + 1)
        ax.hist(np.degrees(q[:, j]), bins=24, range=(np.degrees(q_lo[j]), np.degrees(q_hi[j])))
        ax.set_title(f"joint {j + 1}", fontsize=8, y=1.0)
        ax.tick_params(labelsize=6)
        ax.set_xlabel("deg", fontsize=7)
    T = robot.fk(q)
    p = T[:, :3, 3] * 1e3
    for k, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
        ax = fig.add_subplot(2, 3, 4 + k)
        ax.plot(p[:, a], p[:, b], ".", ms=3)
        ax.set_xlabel(f"{'xyz'[a]} (mm, base)", fontsize=7)
        ax.set_ylabel(f"{'xyz'[b]} (mm, base)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(f"Plan coverage: {q.shape[0]} poses (joint angles; flange positions)")
    fig.tight_layout()
    return fig


def joint_figure(curves: JointCurves, fitted: FittedModel | None = None) -> Figure:
    """One joint's six error motions with bands, in one row (compact; no tight_layout).

    A motion the data cannot identify (every coefficient held at zero, no band) is labelled
    "not identifiable" instead of drawn as a flat zero line, which would read as "no error";
    one the model does not have says "not in the model"."""
    fig = Figure(figsize=(12.0, 2.4))
    fig.subplots_adjust(left=0.05, right=0.99, bottom=0.2, top=0.8, wspace=0.45)
    th = np.degrees(curves.theta)
    for m in range(6):
        ax = fig.add_subplot(1, 6, m + 1)
        v = curves.values[m] * 1e3
        h = curves.half_width[m] * 1e3
        ax.set_title(f"{MOTIONS[m]}: {MOTION_WORDS[MOTIONS[m]]}", fontsize=7, y=1.0)
        state = _motion_state(fitted, curves.joint, m, v, h)
        if state:
            ax.set_facecolor("#f2f2f2")
            ax.text(
                0.5,
                0.5,
                state,
                ha="center",
                va="center",
                fontsize=8,
                color="0.3",
                transform=ax.transAxes,
            )
            ax.set_yticks([])
            ax.set_xlabel("deg", fontsize=7, labelpad=1)
            ax.tick_params(labelsize=6, pad=1)
            continue
        ax.fill_between(th, v - h, v + h, color="#88ccee", alpha=0.6, lw=0)
        ax.plot(th, v, color="#224488", lw=1.2)
        ax.set_ylabel("mm" if m < 3 else "mrad", fontsize=7, labelpad=1)
        ax.set_xlabel("deg", fontsize=7, labelpad=1)
        ax.tick_params(labelsize=6, pad=1)
    fig.suptitle(f"Joint {curves.joint}: error motions with {curves.level:.0%} bands", fontsize=9)
    return fig


def _motion_state(fitted: FittedModel | None, joint: int, m: int, v: F, h: F) -> str:
    """'' for a motion to draw; else why it is not drawn."""
    if fitted is not None:
        if fitted.spec.orders[joint, m] < 0:
            return "not in the model"
        prefix = f"j{joint}.{MOTIONS[m]}."
        labels = [lb for lb in fitted.labels if lb.startswith(prefix)]
        if labels and all(lb in set(fitted.unidentifiable) for lb in labels):
            return "not identifiable"
    if not np.any(v) and not np.any(h):
        return "not identifiable"
    return ""


def _iso_figure(stats: list[PoseStats]) -> Figure:
    rot = all(s.accuracy_abc is not None for s in stats)
    fig = Figure(figsize=(8.0, 5.6 if rot else 3.2))
    ax = fig.add_subplot(2 if rot else 1, 1, 1)
    x = np.arange(len(stats))
    ax.bar(x - 0.2, [s.accuracy * 1e3 for s in stats], 0.4, label="AP (accuracy)")
    ax.bar(x + 0.2, [s.repeatability * 1e3 for s in stats], 0.4, label="RP (repeatability)")
    ax.set_xticks(x, [s.pose_id for s in stats], fontsize=7, rotation=45)
    ax.set_ylabel("mm")
    ax.legend(fontsize=7)
    ax.set_title("ISO 9283-style pose accuracy and repeatability")
    if rot:
        ax2 = fig.add_subplot(2, 1, 2)
        ap = np.array([s.accuracy_abc for s in stats]) * 1e3
        rp = np.array([s.repeatability_abc for s in stats]) * 1e3
        for k, (name, c) in enumerate(zip("abc", ("#4477aa", "#ee6677", "#228833"), strict=True)):
            ax2.errorbar(
                x + (k - 1) * 0.2, ap[:, k], yerr=rp[:, k], fmt="o", ms=3, color=c,
                capsize=2, label=f"AP {name} ± RP {name}",
            )  # fmt: skip
        ax2.axhline(0.0, color="0.5", lw=0.8)
        ax2.set_xticks(x, [s.pose_id for s in stats], fontsize=7, rotation=45)
        ax2.set_ylabel("mrad (about base x, y, z)")
        ax2.legend(fontsize=7)
    fig.tight_layout()
    return fig


def trend_figure(result: TrendResult) -> Figure:
    """Main figures over time with the EWMA control limits, the baseline marked."""
    figs = [f for f in ("mean", "std", "max") if f in result.charts]
    fig = Figure(figsize=(9.0, 2.6 * max(len(figs), 1)))
    t = [datetime.fromtimestamp(v, UTC) for v in result.t_s]
    b = result.baseline_index
    for k, f in enumerate(figs):
        ax = fig.add_subplot(len(figs), 1, k + 1)
        ax.plot(t, result.figures_mm[f], "o-", ms=4, label=f"{f} (mm)")
        ch = result.charts[f]
        ax.plot(t[b:], ch.ewma_mm, "-", color="#228833", lw=1, label="EWMA")
        ax.plot(t[b:], ch.ucl_mm, "--", color="#cc3311", lw=1, label="control limit")
        ax.axvline(t[b], color="0.5", ls=":", lw=1)
        seen = [v for v in (*result.figures_mm[f], *ch.ewma_mm) if math.isfinite(v)]
        if result.threshold_mm is not None and f == result.threshold_figure:
            ax.axhline(result.threshold_mm, color="k", lw=1, label="spec")
            seen.append(result.threshold_mm)
        # with 2-3 runs the limit's σ comes from the runs' own differences and can sit far
        # above the data (8 mm over 1 mm figures): the axis follows the data, not the limit
        top = max(seen) * 1.35 if seen else 1.0
        ucl = [u for u in ch.ucl_mm if math.isfinite(u)]
        if ucl and max(ucl) > top:
            ax.text(
                0.99,
                0.97,
                f"control limit up to {max(ucl):.2f} mm (few runs: σ not yet known)",
                transform=ax.transAxes,
                ha="right",
                va="top",
                fontsize=7,
                color="#cc3311",
            )
        ax.set_ylim(0.0, top)
        ax.set_ylabel(f"{f} TCP error (mm)", fontsize=8)
        ax.legend(fontsize=7, loc="upper left")
        ax.tick_params(labelsize=7)
    fig.autofmt_xdate()
    fig.suptitle("Workspace TCP error over time (dotted: baseline)")
    fig.tight_layout()
    return fig


# ------------------------------------------------------------------------ sections


def verdict_section(j: Judgement, previous: tuple[HealthVerdict, str] | None = None) -> Section:
    """The verdict in the technician's words (:meth:`~.verdict.Judgement.lines`, the same at
    every door): against the spec, against the baseline, what to do; then the top missing
    effect and the reference conditions.  ``previous``: the verdict report.json carried
    before, when this report turned it around (said, never silent)."""
    lines = list(j.lines())
    top = j.top_missing_effect
    lines.append(
        f"top missing effect: {top.effect}" if top is not None else "top missing effect: none"
    )
    if j.conditions:
        lines.append(j.conditions)
    if j.uncertainty:
        lines.append(j.uncertainty)
    data = j.as_dict()
    if previous is not None:
        was, why = previous
        lines.insert(1, f"(this report changed the verdict from {was.value.upper()}: {why})")
        data["previous"] = {"verdict": was.value, "reason": why}
    return Section("verdict", "Verdict", tuple(lines), data=data)


def summary_section(
    fitted: FittedModel, run_id: str, robot: str | None, meta: Mapping[str, str]
) -> Section:
    """Robot, run, plan hash, cell, calibration, software; the fit's lines."""
    lines = [
        f"robot: {fitted.robot.name}" + (f" ({robot})" if robot else ""),
        f"errors against the nominal kinematics of {nominal_of(fitted.robot)}",
        f"run: {run_id}" + (f", {meta['time_utc']}" if "time_utc" in meta else ""),
    ]
    for k in ("plan_hash", "cell", "calibration_id", "software_version"):
        lines.append(f"{k.replace('_', ' ')}: {meta.get(k, '(unknown)')}")
    lines += list(fitted.summary())
    return Section("summary", "Summary", tuple(lines), data={"meta": dict(meta), "run_id": run_id})


def coverage_section(
    fitted: FittedModel, q_plan: F | None, source: str, *, plots: bool = True
) -> Section:
    """The commanded joint angles over each joint's modelled range (paper Fig. 6)."""
    title = "Plan coverage (paper Fig. 6)"
    if q_plan is None:
        return Section("coverage", title, missing="no plan.json and no measurements.csv")
    spec = fitted.spec
    span = np.ptp(q_plan, axis=0) / (spec.q_hi - spec.q_lo)
    fig = (
        (
            Plot(
                "coverage",
                "Plan coverage",
                _png(_coverage_figure(fitted.robot, q_plan, spec.q_lo, spec.q_hi)),
            ),
        )
        if plots
        else ()
    )
    return Section(
        "coverage",
        title,
        (
            f"{q_plan.shape[0]} poses from {source}",
            "share of each joint's modelled range spanned: "
            + ", ".join(f"j{j + 1} {s:.0%}" for j, s in enumerate(span)),
        ),
        plots=fig,
        data={"n_poses": int(q_plan.shape[0]), "range_share": span.tolist()},
    )


def workspace_section(ws: WorkspaceError, *, plots: bool = True) -> Section:
    """The model's TCP error over the whole workspace (paper Fig. 7)."""
    cond = ws.conditions.describe()
    return Section(
        "workspace",
        "Workspace TCP error (paper Fig. 7)",
        (
            f"mean {ws.mean * 1e3:.3f} mm, std {ws.std * 1e3:.3f} mm, "
            f"95 % {ws.p95 * 1e3:.3f} mm, max {ws.max * 1e3:.3f} mm "
            f"over {ws.n_samples} joint commands uniform in the modelled ranges"
            + (f", {cond}" if cond else ""),
        ),
        plots=(
            (Plot("workspace_hist", "Workspace error histogram", _png(workspace_histogram(ws))),)
            if plots
            else ()
        ),
        data=ws.as_dict(),
    )


def curves_section(
    curves: Sequence[JointCurves], fitted: FittedModel, *, plots: bool = True
) -> Section:
    """Each joint's six error motions with 95 % bands (paper Fig. 8)."""
    return Section(
        "curves",
        "Error motions of every joint, 95 % bands (paper Fig. 8)",
        ("bands: sampling uncertainty of the estimate; model error is not in them",),
        plots=tuple(
            Plot(f"curves_j{c.joint}", f"Joint {c.joint}", _png(joint_figure(c, fitted)))
            for c in curves
        )
        if plots
        else (),
        data={"joint_curves": [c.as_dict() for c in curves]},
    )


def residuals_section(
    fitted: FittedModel, meas: Measurements | None, *, plots: bool = True
) -> Section:
    """Measured versus model (the data the model was fitted to)."""
    title = "Measured versus model"
    if meas is None:
        return Section(
            "residuals", title, missing="measurements.csv missing or not the fitted data"
        )
    return Section(
        "residuals",
        title,
        (f"rms position residual {fitted.rms_pos * 1e3:.4f} mm",),
        plots=(Plot("residuals", "Residuals", _png(residual_plot(fitted, meas))),) if plots else (),
        data={"rms_pos_mm": fitted.rms_pos * 1e3},
    )


def diagnosis_section(doc: Mapping[str, Any] | None) -> Section:
    """Which physical effect the model misses: the candidates that matter in the table, the
    rest folded away (``doc``: the ``diagnose --json`` document, None when there is none)."""
    title = "Diagnosis: which physical effect is missing"
    if doc is None:
        return Section("diagnosis", title, missing="no diagnosis.json (quickhealth diagnose …)")
    head = ("effect", "score", "predicted RMS drop (mm)", "evidence")
    rows, small = [head], [head]
    for c in doc.get("candidates", [])[:8]:
        row = (
            str(c.get("effect")),
            f"{float(c.get('score', math.nan)):.2f}",
            f"{float(c.get('predicted_rms_drop_mm', math.nan)):.4f}",
            str(c.get("evidence", "")),
        )
        # the candidates that matter stay in view; "too small to matter" and the
        # not-significant rest fold away
        (rows if c.get("significant", False) else small).append(row)
    lines = [f"verdict: {doc.get('verdict')}"]
    if len(rows) == 1:
        lines.append("no candidate effect matters")
    return Section(
        "diagnosis",
        title,
        tuple(lines),
        table=tuple(rows) if len(rows) > 1 else (),
        data=dict(doc),
        folded=tuple(small) if len(small) > 1 else (),
        folded_title=f"{len(small) - 1} candidates too small to matter or not significant",
    )


def trend_section(
    trend: TrendResult | None,
    runs: Sequence[tuple[str, str]] = (),
    *,
    missing: str = "",
    plots: bool = True,
) -> Section:
    """The robot's trend up to this run (``runs``: each run's id and time, UTC), or why there
    is none (``missing``)."""
    title = "Trend against the baseline"
    if trend is None:
        return Section("trend", title, missing=missing)
    b = trend.baseline_index
    flags = trend.flags()
    lines = [
        f"{len(runs)} runs; baseline {runs[b][0]}",
        "trend: " + ("FLAGGED" if flags else "no flag against the baseline"),
    ]
    lines += flags
    lines += [p.words() for p in trend.prognoses.values()]
    lines += [f"warning: {w}" for w in trend.warnings]
    rows = [("run", "time (UTC)", "mean (mm)", "std (mm)", "max (mm)", "flags")]
    for i, (run_id, time_utc) in enumerate(runs):
        rows.append(
            (
                run_id + (" (baseline)" if i == b else ""),
                time_utc,
                *(f"{trend.figures_mm[f][i]:.3f}" for f in ("mean", "std", "max")),
                str(len(trend.flags(i))),
            )
        )
    return Section(
        "trend",
        title,
        tuple(lines),
        table=tuple(rows),
        plots=(Plot("trend", "Trend", _png(trend_figure(trend))),) if plots else (),
        data=trend_to_json(trend),
    )


def iso_section(
    stats: Sequence[PoseStats], meas: Measurements | None, *, plots: bool = True
) -> Section:
    """ISO 9283-style pose accuracy and repeatability at the poses visited more than once."""
    title = "ISO 9283-style pose accuracy and repeatability"
    if meas is None or meas.pose_id is None:
        return Section(
            "iso9283", title, missing="no pose_id column: the plan has no repeated poses"
        )
    rot = meas.has_orientation
    if not stats:
        return Section(
            "iso9283",
            title,
            not_applicable=(
                f"the plan visits each of its {len(set(meas.pose_id))} poses once: ISO 9283 "
                "accuracy (AP) and repeatability (RP) need poses visited more than once (one "
                "pose_id on several rows)"
            ),
        )

    def abc(v: F, signed: bool) -> str:
        return " / ".join(f"{x * 1e3:+.4f}" if signed else f"±{x * 1e3:.4f}" for x in v)

    header = ("pose", "visits", "AP (mm)", "RP (mm)")
    if rot:
        header += ("AP a / b / c (mrad)", "RP a / b / c (mrad)")
    rows = [header]
    for s in stats:
        row: tuple[str, ...] = (
            s.pose_id,
            str(s.n),
            f"{s.accuracy * 1e3:.4f}",
            f"{s.repeatability * 1e3:.4f}",
        )
        if rot:
            row += (abc(s.accuracy_abc, True), abc(s.repeatability_abc, False))
        rows.append(row)
    lines = [
        "AP: distance of the mean attained position from the commanded one (nominal "
        "kinematics with the identified base and tool); RP = l̄ + 3 S_l"
        + (
            "; orientation (§7.2.1, §7.2.3): AP a/b/c = mean attained minus commanded "
            "rotation about the robot base's x/y/z axes, RP a/b/c = ±3 S"
            if rot
            else "; position only (the data have no orientation)"
        ),
        f"worst AP {max(s.accuracy for s in stats) * 1e3:.4f} mm, worst RP "
        f"{max(s.repeatability for s in stats) * 1e3:.4f} mm"
        + (
            f"; orientation: worst |AP a/b/c| "
            f"{max(float(np.abs(s.accuracy_abc).max()) for s in stats) * 1e3:.4f} mrad, "
            f"worst RP a/b/c ±{max(float(s.repeatability_abc.max()) for s in stats) * 1e3:.4f}"
            " mrad"
            if rot
            else ""
        ),
    ]
    poses = []
    for s in stats:
        d: dict[str, Any] = {
            "pose_id": s.pose_id,
            "n": s.n,
            "ap_mm": s.accuracy * 1e3,
            "rp_mm": s.repeatability * 1e3,
        }
        if rot:
            d["ap_abc_mrad"] = (s.accuracy_abc * 1e3).tolist()
            d["rp_abc_mrad"] = (s.repeatability_abc * 1e3).tolist()
        poses.append(d)
    return Section(
        "iso9283",
        title,
        tuple(lines),
        table=tuple(rows),
        plots=(Plot("iso9283", "ISO 9283", _png(_iso_figure(list(stats)))),) if plots else (),
        data={"orientation": rot, "poses": poses},
    )


# ------------------------------------------------------------------------ rendering


_CSS = """
body{font-family:system-ui,sans-serif;max-width:1100px;margin:1em auto;padding:0 1em;color:#222}
h1{font-size:1.4em}h2{font-size:1.15em;border-bottom:1px solid #ccc;margin-top:1.6em}
img.plot{max-width:100%;display:block;margin:.6em 0;border:1px solid #eee}
table{border-collapse:collapse;font-size:.85em}td,th{border:1px solid #ccc;padding:2px 6px}
.missing{color:#a60}.not-applicable{color:#555}.flag{color:#b00;font-weight:bold}pre{white-space:pre-wrap}
.verdict{border:2px solid #888;border-radius:6px;padding:.4em 1em;margin:.6em 0}
.verdict p{margin:.3em 0}.verdict-line{font-size:1.25em;font-weight:bold}
.verdict.healthy{border-color:#2a7;background:#effaf3}
.verdict.degraded{border-color:#d90;background:#fff8e6}
.verdict.flagged{border-color:#c22;background:#fdeeee}
"""


def _table(rows: tuple[tuple[str, ...], ...]) -> list[str]:
    e = html.escape
    head, *body = rows
    out = ["<table><tr>" + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr>"]
    out += ["<tr>" + "".join(f"<td>{e(c)}</td>" for c in r) + "</tr>" for r in body]
    out.append("</table>")
    return out


def script_json(doc: object) -> str:
    """``doc`` as JSON that can sit inside a ``<script>`` element: ``<``, ``>`` and ``&`` as
    ``\\u003c``, ``\\u003e``, ``\\u0026`` (the same JSON to a parser), so no text in it (a CSV
    comment holding ``<!--<script>`` or ``</script>``) can open a comment, close the element
    or start another one."""
    text = json.dumps(doc)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def render_html(rep: Report) -> str:
    """One self-contained HTML page: no external files, every figure a PNG data URI."""
    e = html.escape
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{e(rep.title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{e(rep.title)}</h1>",
    ]
    nav = (
        "<nav>"
        + " · ".join(f'<a href="#{s.key}">{e(s.title)}</a>' for s in rep.sections)
        + "</nav>"
    )
    for k, s in enumerate(rep.sections):
        if s.key == "verdict":
            v = str(s.data.get("verdict", ""))
            out.append(f'<section id="verdict" class="verdict {e(v)}">')
            out += [
                f'<p id="verdict-line" class="verdict-line">{e(s.lines[0])}</p>',
                *(f'<p id="verdict-{i}">{e(x)}</p>' for i, x in enumerate(s.lines[1:], 1)),
                "</section>",
            ]
            if k == 0:
                out.append(nav)
            continue
        if k == 0:
            out.append(nav)
        out.append(f'<section id="{s.key}"><h2>{e(s.title)}</h2>')
        if s.missing:
            out.append(f'<p class="missing">Not available: {e(s.missing)}</p>')
        if s.not_applicable:
            out.append(f'<p class="not-applicable">Not applicable: {e(s.not_applicable)}</p>')
        for line in s.lines:
            cls = ' class="flag"' if line.startswith(("trend: FLAGGED", "joint ")) else ""
            out.append(f"<p{cls}>{e(line)}</p>")
        if s.table:
            out += _table(s.table)
        if s.folded:
            out.append(f"<details><summary>{e(s.folded_title)}</summary>")
            out += _table(s.folded)
            out.append("</details>")
        for p in s.plots:
            b64 = base64.b64encode(p.png).decode("ascii")
            out.append(
                f'<img class="plot" id="plot-{p.key}" alt="{e(p.title)}" '
                f'src="data:image/png;base64,{b64}">'
            )
        out.append("</section>")
    payload = script_json(_plain(rep.to_dict()))
    out.append(f'<script type="application/json" id="report-json">{payload}</script>')
    out.append("</body></html>")
    return "\n".join(out)
