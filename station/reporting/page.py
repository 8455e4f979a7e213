"""The run report as a page: its sections (text, tables, figures) and one self-contained HTML file.

Sections, in the order a reader needs them:

0. verdict          healthy, degraded or flagged against the accuracy spec and the baseline,
                    why and what to do (the words every door shows); the top missing effect
                    (the first screen)
1. summary          robot, run, plan hash, cell, calibration, software; the fit's lines
2. calibration      before and after: TCP error at measured poses with the nominal kinematics
                    and with the model (held-out poses where there are some)
3. plan coverage    commanded joint angles over each joint's range and the TCP positions
                    (paper Fig. 6)
4. workspace error  how large (histogram, the spec drawn) and where (a map of the TCP
                    positions coloured by error) over the whole workspace (Fig. 7)
5. error curves     each joint's six error motions as variation about their offset, with
                    95 % bands, every joint on the same scales (Fig. 8)
6. residuals        measured minus model, per pose and against each joint angle
7. diagnosis        which physical effect the model misses, if any
8. trend            the robot's figures over time against its baseline, control limits,
                    the spec, root-cause hints (when the run is archived)
9. ISO 9283         pose accuracy AP and repeatability RP at plan poses visited repeatedly:
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
from typing import Any

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from ...identify.fit import FittedModel  # noqa: E402
from ...identify.measurements import Measurements  # noqa: E402
from ...identify.report import residual_plot  # noqa: E402
from ...identify.robot import nominal_of  # noqa: E402
from ...identify.trend import TrendResult  # noqa: E402
from ...identify.workspace import JointCurves, WorkspaceError, WorkspaceMap  # noqa: E402
from ..formats.common import json_plain as _plain  # noqa: E402
from ..formats.report import trend_to_json  # noqa: E402
from . import figures  # noqa: E402
from .calibration import BeforeAfter  # noqa: E402
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
                _png(figures.coverage_figure(fitted.robot, q_plan, spec.q_lo, spec.q_hi)),
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


def workspace_section(
    ws: WorkspaceError, wm: WorkspaceMap, spec_mm: float | None, *, plots: bool = True
) -> Section:
    """The model's TCP error over the whole workspace (paper Fig. 7) and where it is: a map
    of the sampled TCP positions coloured by their error, the spec on both."""
    cond = ws.conditions.describe()
    w = wm.worst
    x, y, z = wm.xyz_base[w] * 1e3
    lines = (
        f"mean {ws.mean * 1e3:.3f} mm, std {ws.std * 1e3:.3f} mm, "
        f"95 % {ws.p95 * 1e3:.3f} mm, max {ws.max * 1e3:.3f} mm "
        f"over {ws.n_samples} joint commands uniform in the modelled ranges"
        + (f", {cond}" if cond else ""),
        f"largest at x {x:.0f}, y {y:.0f}, z {z:.0f} mm in the robot base frame (joints "
        + ", ".join(f"{v:.0f}" for v in np.degrees(wm.q[w]))
        + " deg)"
        + (
            f"; {np.mean(wm.err * 1e3 > spec_mm):.1%} of the workspace is above the spec"
            if spec_mm is not None
            else ""
        ),
    )
    return Section(
        "workspace",
        "Workspace TCP error: how large and where (paper Fig. 7)",
        lines,
        plots=(
            Plot("workspace_hist", "Histogram", _png(figures.histogram_figure(ws, spec_mm))),
            Plot("workspace_map", "Map", _png(figures.workspace_map_figure(wm, spec_mm))),
        )
        if plots
        else (),
        data={**ws.as_dict(), "worst_xyz_base_mm": [x, y, z]},
    )


def calibration_section(
    sets: Sequence[BeforeAfter], spec_mm: float | None, *, plots: bool = True
) -> Section:
    """Before and after calibration: the TCP error at measured poses with the nominal
    kinematics against the identified model (held-out poses where there are some)."""
    title = "Before and after calibration"
    if not sets:
        return Section(
            "calibration", title, missing="measurements.csv missing or not the fitted data"
        )
    rows = [
        ("poses", "n", "nominal RMS (mm)", "nominal max (mm)", "model RMS (mm)", "model max (mm)")
    ]
    for s in sets:
        d = s.as_dict()
        rows.append(
            (s.label, str(s.n), *(f"{d[k]:.3f}" for k in ("nominal_rms_mm", "nominal_max_mm",
                                                           "model_rms_mm", "model_max_mm")))
        )  # fmt: skip
    best = sets[-1]
    lines = (
        f"with its nominal kinematics the robot misses the measured target by "
        f"{best.rms('before') * 1e3:.3f} mm RMS ({best.before.max() * 1e3:.3f} mm at most); with "
        f"the identified model, {best.rms('after') * 1e3:.3f} mm RMS "
        f"({best.after.max() * 1e3:.3f} mm at most), on {best.label}",
        "nominal: the published kinematics with the registered base and tool (the set-up is not "
        "robot error); model: the fitted error model"
        + ("" if len(sets) > 1 else "; no held-out data beside the run (RUN/heldout.csv)"),
    )
    return Section(
        "calibration",
        title,
        lines,
        table=tuple(rows),
        plots=(
            Plot(
                "calibration", "Before and after", _png(figures.before_after_figure(sets, spec_mm))
            ),
        )
        if plots
        else (),
        data={"sets": [s.as_dict() for s in sets]},
    )


def curves_section(
    curves: Sequence[JointCurves], fitted: FittedModel, *, plots: bool = True
) -> Section:
    """Each joint's six error motions as variation about their offset, 95 % bands, every joint
    on the same scales (paper Fig. 8)."""
    lim = figures.shared_limits(curves)
    return Section(
        "curves",
        "Error motions of every joint: how they vary over each joint's range (paper Fig. 8)",
        (
            "each panel shows the motion minus its mean over the range (the offset, in its "
            f"title); every joint on the same scales (±{lim[0]:.3g} mm, ±{lim[1]:.3g} mrad), "
            "so a flat panel is a motion that does not change with the joint",
            "bands: sampling uncertainty of the estimate; model error is not in them",
        ),
        plots=tuple(
            Plot(
                f"curves_j{c.joint}", f"Joint {c.joint}", _png(figures.joint_figure(c, fitted, lim))
            )
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
    flags = trend.change_flags()
    lines = [
        f"{len(runs)} runs; baseline {runs[b][0]}",
        "trend: " + ("changed since the baseline" if flags else "no change since the baseline"),
    ]
    lines += flags
    lines += [p.words() for p in trend.prognoses.values()]
    lines += [f"warning: {w}" for w in trend.warnings]
    rows = [("run", "time (UTC)", "mean (mm)", "std (mm)", "max (mm)", "changes")]
    for i, (run_id, time_utc) in enumerate(runs):
        rows.append(
            (
                run_id + (" (baseline)" if i == b else ""),
                time_utc,
                *(f"{trend.figures_mm[f][i]:.3f}" for f in ("mean", "std", "max")),
                str(len(trend.change_flags(i))),
            )
        )
    return Section(
        "trend",
        title,
        tuple(lines),
        table=tuple(rows),
        plots=(Plot("trend", "Trend", _png(figures.trend_figure(trend))),) if plots else (),
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
                "accuracy (AP) and repeatability (RP) need poses visited more than once "
                "(plan --iso9283 adds the ISO cube's five poses, visited in cycles)"
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
        plots=(Plot("iso9283", "ISO 9283", _png(figures.iso_figure(list(stats)))),)
        if plots
        else (),
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
