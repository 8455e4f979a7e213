"""The report of a fitted run: what it finds, the one verdict, report.html and report.json.

:func:`build_report` gathers what a run folder and the archive say (the fitted model, the
data, the plan, the workspace error, the joint curves, the diagnosis, the trend against the
baseline, ISO 9283 statistics), judges the run (:func:`quickhealth.station.reporting.verdict.judge`) and
lays it out as the page's sections (:mod:`quickhealth.station.reporting.page`).
:func:`report_run` is the door every producer uses (``quickhealth report``, the TUI's Results
screen, ``reprocess``): it writes report.html and adds the sections, the verdict and the
``run`` object to report.json, keeping its schema.

SYNOPSIS::

    res = report_run(Path("runs/r1"), archive=Archive.open(), robot="ur5-cell3")
    res.report.judgement.lines()
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...identify.diagnose import diagnose, state_from_fitted
from ...identify.errors import InputError
from ...identify.fit import FittedModel
from ...identify.measurements import Measurements
from ...identify.trend import TrendResult, assess_trend
from ...identify.workspace import (
    JointCurves,
    WorkspaceError,
    WorkspaceMap,
    all_joint_curves,
    error_distribution,
    reference_conditions,
    workspace_map,
)
from ..archive import Archive, missing_words, run_metadata, run_state, trend_runs
from ..formats import measurements as measurements_file
from ..formats import model as model_file
from ..formats import report as report_file
from ..formats.common import write_text_atomic
from ..fsio import write_atomic, write_figure
from ..planning.planfile import plan_joints
from ..reporting import page
from ..reporting.calibration import BeforeAfter, before_after, heldout_file
from ..reporting.iso9283 import run_pose_stats
from ..reporting.pdf import report_page
from ..reporting.verdict import (
    Figures,
    HealthVerdict,
    Judgement,
    MissingEffect,
    Spec,
    judge,
    recorded_verdict,
    spec_of_run,
)
from .options import ReportOptions

#: The report's sections that report.json keeps (beside the fit's keys).
JSON_SECTIONS = ("calibration", "coverage", "diagnosis", "trend", "iso9283", "verdict")


@dataclass(frozen=True)
class RunReport:
    """A run's report: the page's sections and the verdict."""

    page: page.Report
    judgement: Judgement
    run_id: str
    robot: str | None
    previous: tuple[HealthVerdict, str] | None = None  # the verdict it turned around, if any
    # what the one-page PDF draws (the page's sections hold the same as figures and words)
    workspace: WorkspaceError | None = None
    workspace_map: WorkspaceMap | None = None
    calibration: tuple[BeforeAfter, ...] = ()
    curves: tuple[JointCurves, ...] = ()
    trend: TrendResult | None = None
    title: str = ""


@dataclass(frozen=True)
class ReportFiles:
    """What :func:`report_run` wrote: the report, report.html (None with ``html=False``) and
    report.json's new content."""

    report: RunReport
    html: Path | None
    report_json: Path
    doc: dict[str, Any]
    pdf: Path | None = None  # the one-page PDF beside report.html
    previous: tuple[HealthVerdict, str] | None = None  # the verdict report.json had, if other

    def turned_words(self) -> str | None:
        """One line when this report turned the verdict report.json carried around, else None."""
        if self.previous is None:
            return None
        was, why = self.previous
        now = self.report.judgement
        return (
            f"note: the verdict changed from {was.value.upper()} ({why}) to "
            f"{now.verdict.value.upper()}: {now.reason}"
        )


def build_report(
    run_dir: str | Path,
    *,
    archive: Archive | None = None,
    robot: str | None = None,
    run_id: str | None = None,
    options: ReportOptions = ReportOptions(),
    meas: Measurements | None = None,
    plots: bool = True,
    in_place_of_archived: bool = False,
    previous: tuple[HealthVerdict, str] | None = None,
) -> RunReport:
    """Gather every section of a run's report and judge the run.

    Parameters
    ----------
    run_dir : path
        Folder with ``model.json`` and ``measurements.csv`` (and optionally ``report.json``,
        ``plan.json``, ``run.json``, ``diagnosis.json``).
    archive : Archive, optional
        For the trend section: the archive holding this robot's runs.
    robot, run_id : str, optional
        The run's robot and id in the archive (run id default: the folder's name).
    meas : Measurements, optional
        The data the model was fitted to (default: the folder's measurements.csv).
    plots : bool
        Draw the figures (report.json alone needs none).
    in_place_of_archived : bool
        The folder stands for the archived run in the trend (a reprocessed copy): the trend
        reads this run's figures and model from the folder, not from the archive.
    previous : (HealthVerdict, str), optional
        The verdict and reason the run's report.json carried: when this report turns it
        around, the verdict section says so (never silently).

    Raises
    ------
    InputError
        The folder has no ``model.json`` (nothing to report).
    """
    d = Path(run_dir)
    if not (d / "model.json").is_file():
        raise InputError(f"{d}: no model.json (fit the run first: quickhealth identify fit)")
    fitted = model_file.read_model(d / "model.json")
    if meas is None and (d / "measurements.csv").is_file():
        meas = measurements_file.read_measurements(d / "measurements.csv", fitted.robot.n_joints)
    if meas is not None and meas.n_poses != fitted.n_poses:
        meas = None  # not the data this model was fitted to
    meta = run_metadata(d)
    rid = run_id or meta.get("run_id") or d.resolve().name
    if archive is not None and robot is not None:  # the index knows what the folder may not
        rec = next((r for r in archive.runs(robot) if r.run_id == rid), None)
        if rec is not None:
            meta = {**meta, **{k: v for k, v in rec.meta.items() if v}, "time_utc": rec.time_utc}

    q_plan, plan_source = _plan_joints(d, meas)
    cond = reference_conditions(fitted)
    wm = workspace_map(fitted, n_samples=options.workspace_samples, conditions=cond)
    ws = error_distribution(wm.q, wm.err, cond)  # the same evaluation as the map's
    curves = all_joint_curves(fitted, n_points=61)
    calib = _before_after(d, fitted, meas)
    diag = run_diagnosis(d, fitted, meas, compute=options.diagnose_if_missing)
    own = d if in_place_of_archived else None
    spec = spec_of_run(d, options.accuracy_spec)
    trend, runs, why = _trend(archive, robot, rid, spec, own)
    judgement = judge(
        Figures.of_report({"workspace": ws.as_dict()}),
        trend=trend,
        missing=MissingEffect.of_diagnosis(diag),
        spec=spec,
        conditions=ws.conditions.describe(),
        uncertainty=_uncertainty_words(fitted),
        baseline_time=_baseline_time(trend, runs),
        no_baseline=why,
    )
    turned = previous if previous is not None and previous[0] is not judgement.verdict else None
    spec_mm = None if spec is None else spec.mm
    sections = (
        page.verdict_section(judgement, turned),
        page.summary_section(fitted, rid, robot, meta),
        page.calibration_section(calib, spec_mm, plots=plots),
        page.coverage_section(fitted, q_plan, plan_source, plots=plots),
        page.workspace_section(ws, wm, spec_mm, plots=plots),
        page.curves_section(curves, fitted, plots=plots),
        page.residuals_section(fitted, meas, plots=plots),
        page.diagnosis_section(diag),
        page.trend_section(trend, runs, missing=why, plots=plots),
        page.iso_section([] if meas is None else run_pose_stats(fitted, meas), meas, plots=plots),
    )
    title = f"quickhealth report: {fitted.robot.name}, run {rid}" + (
        f" (robot {robot})" if robot else ""
    )
    report = page.Report(title=title, run_dir=str(d), sections=sections)
    return RunReport(
        report, judgement, rid, robot, turned, ws, wm, calib, tuple(curves), trend, title
    )


def _before_after(
    d: Path, fitted: FittedModel, meas: Measurements | None
) -> tuple[BeforeAfter, ...]:
    """Before and after calibration on the fitted poses and, where a held-out file lies beside
    the run (:func:`~..reporting.calibration.heldout_file`), on those."""
    if meas is None:
        return ()
    out = [before_after(fitted, meas, "the fitted poses")]
    src = (
        report_file.read_report(d / "report.json").get("input")
        if (d / "report.json").is_file()
        else None
    )
    held = heldout_file(d, src if isinstance(src, str) else None)
    if held is not None:
        try:
            hm = measurements_file.read_measurements(held, fitted.robot.n_joints)
        except InputError:
            return tuple(out)
        out.append(before_after(fitted, hm, f"held-out poses ({held.name})"))
    return tuple(out)


def report_run(
    run_dir: str | Path,
    *,
    archive: Archive | None = None,
    robot: str | None = None,
    run_id: str | None = None,
    options: ReportOptions = ReportOptions(),
    meas: Measurements | None = None,
    html: Path | None = None,
    write_html: bool = True,
    in_place_of_archived: bool = False,
    record_verdict: bool = True,
) -> ReportFiles:
    """Report a fitted run folder: report.html (at ``html``, default ``RUN_DIR/report.html``;
    none with ``write_html=False``) and report.json with the report's sections, its verdict
    and the ``run`` object added (schema kept).  With ``record_verdict``, an archived run's
    healthy flag in the index becomes the verdict's (the baseline is the first healthy run).

    Raises
    ------
    InputError
        No model.json or report.json in the folder, or a report.json that is not a complete
        fit report of its schema (fit the run first).
    """
    d = Path(run_dir)
    fit_first = (
        f"fit the run first: quickhealth identify fit {d / 'measurements.csv'} --robot ROBOT "
        f"--out {d}"
    )
    for name in ("model.json", "report.json"):
        if not (d / name).is_file():
            raise InputError(f"{d}: no {name} ({fit_first})")
    rp = d / "report.json"
    doc = report_file.read_report(rp)  # a quickhealth report of a schema this version reads
    report_file.check_report(doc, str(rp), complete=False)  # the fit's figures are there
    if doc["schema"] == report_file.REPORT_SCHEMA:  # every key of /2, or it is not a /2 file
        try:
            report_file.check_report(doc, str(rp))
        except InputError as exc:
            raise InputError(f"{exc}: not a complete report.json ({fit_first})") from None
    before = recorded_verdict(doc)
    rep = build_report(
        d,
        archive=archive,
        robot=robot,
        run_id=run_id,
        options=options,
        meas=meas,
        plots=write_html,
        in_place_of_archived=in_place_of_archived,
        previous=before,
    )
    sections = rep.page.to_dict()["sections"]
    j = rep.judgement
    spec = j.spec
    run = {
        "run_id": rep.run_id,
        "robot_name": robot,
        "verdict": j.verdict.value,
        "healthy": j.healthy,
        "threshold_mm": None if spec is None else spec.mm,
        "threshold_figure": None if spec is None else spec.figure.value,
    }
    extra = {"spec": spec.as_dict()} if spec is not None else {}
    text = report_file.with_sections(
        doc, {k: sections[k] for k in JSON_SECTIONS}, run=run, extra=extra
    )
    out = pdf = None
    if write_html:
        out = Path(html) if html is not None else d / "report.html"
        write_text_atomic(out, page.render_html(rep.page))
        pdf = write_figure(report_page(rep), out.with_suffix(".pdf"), dpi=150, format="pdf")
    write_atomic(rp, text)
    if record_verdict and archive is not None and robot is not None:
        rec = next((r for r in archive.runs(robot) if r.run_id == rep.run_id), None)
        # a row whose archive folder was deleted behind the index is left as it is (the
        # trend refuses to judge that run): the verdict here was made without it
        if rec is not None and archive.folder(rec).is_dir():
            archive.set_healthy(robot, rep.run_id, j.fit_as_baseline)
    return ReportFiles(
        rep, out, rp, json.loads(text), None if pdf is None else Path(pdf), rep.previous
    )


def run_diagnosis(
    run_dir: Path,
    fitted: FittedModel | None = None,
    meas: Measurements | None = None,
    *,
    compute: bool = True,
) -> dict[str, Any] | None:
    """The run's diagnosis, as every verdict uses it: the folder's ``diagnosis.json``, else
    the one its report.json holds for this model, else (``compute``) the diagnosis of the
    fitted model against its measurements (``fitted``, ``meas``: read from the folder when
    not given); None when there is none to read or compute."""
    d = Path(run_dir)
    diag = _json(d / "diagnosis.json")
    if diag is None and (d / "report.json").is_file():
        section = report_file.read_report(d / "report.json").get("diagnosis")
        diag = section if isinstance(section, dict) and "verdict" in section else None
    if diag is not None or not compute:
        return diag
    if fitted is None and (d / "model.json").is_file():
        fitted = model_file.read_model(d / "model.json")
    if meas is None and fitted is not None and (d / "measurements.csv").is_file():
        meas = measurements_file.read_measurements(d / "measurements.csv", fitted.robot.n_joints)
    if fitted is None or meas is None or meas.n_poses != fitted.n_poses:
        return None
    return diagnose(state_from_fitted(fitted), meas).to_dict(top=8)


def _json(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}:{exc.colno}: not valid JSON: {exc.msg}") from None
    return doc if isinstance(doc, dict) else None


def _plan_joints(d: Path, meas: Measurements | None) -> tuple[NDArray[np.float64] | None, str]:
    """The commanded joints (rad) of the folder's plan.json, else the measured poses."""
    q = plan_joints(d / "plan.json")
    if q is not None:
        return q, "plan.json"
    if meas is not None:
        return meas.q, "measurements.csv (executed poses)"
    return None, ""


def _uncertainty_words(fitted: FittedModel) -> str:
    """What the verdict line says when the bands use a scatter estimated from the residuals
    (the stated instrument uncertainty was too small for them), else ""."""
    n = fitted.noise
    if not n.rescaled:
        return ""
    added = [
        f"{v * k:.3g} {unit}"
        for v, k, unit in ((n.excess_pos, 1e3, "mm"), (n.excess_rot, 1e3, "mrad"))
        if v > 0
    ]
    return (
        "uncertainty estimated from the residuals (the stated instrument uncertainty was too "
        f"small: {' and '.join(added) or 'a scatter'} added per axis)"
    )


def _baseline_time(trend: TrendResult | None, runs: list[tuple[str, str]]) -> str:
    """When the trend's baseline run was measured (ISO 8601), "" without a trend."""
    if trend is None:
        return ""
    return runs[trend.baseline_index][1] if trend.baseline_index < len(runs) else ""


def _trend(
    archive: Archive | None,
    robot: str | None,
    rid: str,
    spec: Spec | None,
    folder: Path | None = None,
) -> tuple[TrendResult | None, list[tuple[str, str]], str]:
    """The robot's trend up to run ``rid``, each run's id and time; or why there is none
    (``folder``: where run ``rid``'s fit is read from instead of its archive folder)."""
    if archive is None or robot is None:
        return None, [], "the run is not archived (quickhealth archive add RUN_DIR --robot NAME)"
    if rid not in [r.run_id for r in archive.runs(robot)]:
        return None, [], f"run {rid} is not in the archive of robot {robot}"
    try:  # runs whose archive folders are missing are left out, and said so
        recs, missing = trend_runs(archive, robot, upto=rid)
    except InputError as exc:
        return None, [], str(exc)
    b = next((i for i, r in enumerate(recs) if r.baseline), None)
    if b is None:
        return None, [], f"robot {robot} has no baseline before this run"
    states = [run_state(archive, r, like=recs[b]) for r in recs[:-1]]
    states.append(run_state(archive, recs[-1], like=recs[b], folder=folder))
    res = assess_trend(
        states,
        b,
        threshold_mm=None if spec is None else spec.mm,
        threshold_figure="max" if spec is None else spec.figure.value,
    )
    if missing:
        res = replace(res, warnings=(*missing_words(archive, missing), *res.warnings))
    return res, [(r.run_id, r.time_utc) for r in recs], ""
