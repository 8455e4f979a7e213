"""The run report: one self-contained HTML file (plots embedded as PNG) and the same as JSON.

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

``build_report`` gathers the numbers and figures from a run folder; ``render_html`` turns them
into the page.  ``report_json`` is the page's content as JSON (also embedded in the page as
``<script type="application/json" id="report-json">``).  Missing inputs give a section that
says what is missing and how to get it ("Not available: ..."), never a silent gap; a section
that does not apply to the run (ISO 9283 on a plan without repeated poses) says why ("Not
applicable: ...").

SYNOPSIS::

    rep = build_report(Path("runs/r1"), archive=Archive.open(), robot="ur5-cell3")
    Path("runs/r1/report.html").write_text(render_html(rep))
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from quickhealth.identify.errors import InputError  # noqa: E402
from quickhealth.identify.robot import nominal_of  # noqa: E402
from quickhealth.station.formats.common import json_plain as _plain  # noqa: E402

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


# ------------------------------------------------------------------------ ISO 9283


@dataclass(frozen=True)
class PoseStats:
    """ISO 9283-style figures of one repeatedly visited pose (m, rad).

    Position: ``accuracy`` AP_P, ``repeatability`` RP_l.  Orientation (pose data only, else
    None), per rotation component a, b, c about the robot base's x, y, z axes:
    ``accuracy_abc`` AP_a, AP_b, AP_c (signed mean deviation from the commanded orientation)
    and ``repeatability_abc`` RP_a, RP_b, RP_c (the ± half-width ``3 S``).
    """

    pose_id: str
    n: int
    accuracy: float  # AP_P: distance of the barycentre of attained positions from the command
    repeatability: (
        float  # RP_l = l̄ + 3 S_l, l = distance of each attained position to the barycentre
    )
    accuracy_abc: F | None = None  # (3,) rad
    repeatability_abc: F | None = None  # (3,) rad


def iso9283_pose_stats(
    pose_id: tuple[str, ...],
    attained: F,
    commanded: F,
    attained_R: F | None = None,
    commanded_R: F | None = None,
    R_meas_base: F | None = None,
) -> list[PoseStats]:
    """Pose accuracy and repeatability (ISO 9283 §7.2.1, §7.2.3) at poses visited ≥ 2 times.

    Parameters
    ----------
    pose_id : tuple of str, length n
    attained : ndarray, shape (n, 3), m
        Measured positions.
    commanded : ndarray, shape (n, 3), m
        Commanded positions in the same frame (the nominal kinematics with the identified
        base and tool).
    attained_R, commanded_R : ndarray, shape (n, 3, 3), optional
        Measured and commanded orientations (same frame): adds the orientation figures.
    R_meas_base : ndarray, shape (3, 3), optional
        The robot base's axes in that frame: the components a, b, c are rotations about them
        (ISO 9283 states orientation in the base coordinate system); default the frame's own.

    Orientation: the attained deviation of visit j is the small rotation
    ``δ_j = log(R_attained,j · R_commandedᵀ)`` expressed in base axes, ``(a_j − a_c, b_j − b_c,
    c_j − c_c)`` to first order; ``AP_abc = mean_j δ_j`` (§7.2.1: ``ā − a_c`` …) and
    ``RP_abc = 3 S`` with ``S = sqrt(Σ (δ_j − δ̄)² / (n − 1))`` per component (§7.2.3).

    Returns
    -------
    list of PoseStats, one per repeated pose, in first-visit order.
    """
    from quickhealth.identify.transforms import log_so3

    delta = None
    if attained_R is not None and commanded_R is not None:
        w = log_so3(np.asarray(attained_R) @ np.swapaxes(np.asarray(commanded_R), -1, -2))
        R_b = np.eye(3) if R_meas_base is None else np.asarray(R_meas_base, float)
        delta = w @ R_b  # rows: R_bᵀ w, the rotation about the base axes
    out = []
    ids = np.asarray(pose_id)
    seen: list[str] = []
    for p in ids:
        if p not in seen:
            seen.append(str(p))
    for p in seen:
        sel = ids == p
        n = int(sel.sum())
        if n < 2:
            continue
        a = attained[sel]
        bary = a.mean(axis=0)
        l = np.linalg.norm(a - bary, axis=1)
        s_l = math.sqrt(float(np.sum((l - l.mean()) ** 2)) / (n - 1))
        ap = float(np.linalg.norm(bary - commanded[sel].mean(axis=0)))
        ap_abc = rp_abc = None
        if delta is not None:
            d = delta[sel]
            ap_abc = d.mean(axis=0)
            rp_abc = 3.0 * d.std(axis=0, ddof=1)
        out.append(PoseStats(p, n, ap, float(l.mean() + 3 * s_l), ap_abc, rp_abc))
    return out


# ------------------------------------------------------------------------ figures


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return buf.getvalue()


def _coverage_figure(robot: Any, q: F, q_lo: F, q_hi: F) -> Figure:
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


def joint_figure(curves: Any, fitted: Any = None) -> Figure:
    """One joint's six error motions with bands, in one row (compact; no tight_layout).

    A motion the data cannot identify (every coefficient held at zero, no band) is labelled
    "not identifiable" instead of drawn as a flat zero line, which would read as "no error";
    one the model does not have says "not in the model"."""
    from quickhealth.identify.errormodel import MOTION_WORDS, MOTIONS

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


def _motion_state(fitted: Any, joint: int, m: int, v: F, h: F) -> str:
    """'' for a motion to draw; else why it is not drawn."""
    if fitted is not None:
        from quickhealth.identify.errormodel import MOTIONS

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


def trend_figure(result: Any) -> Figure:
    """Main figures over time with the EWMA control limits, the baseline marked."""
    from datetime import UTC, datetime

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
            ax.axhline(result.threshold_mm, color="k", lw=1, label="threshold")
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


# ------------------------------------------------------------------------ building


def _json(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}:{exc.colno}: not valid JSON: {exc.msg}") from None
    return doc if isinstance(doc, dict) else None


def build_report(
    run_dir: str | Path,
    *,
    archive: Any = None,
    robot: str | None = None,
    run_id: str | None = None,
    threshold_mm: float | None = None,
    diagnose_if_missing: bool = True,
    workspace_samples: int = 5000,
) -> Report:
    """Gather every section of a run's report.

    Parameters
    ----------
    run_dir : path
        Folder with ``model.json`` and ``measurements.csv`` (and optionally ``report.json``,
        ``plan.json``, ``run.json``, ``diagnosis.json``).
    archive : Archive, optional
        For the trend section: the archive holding this robot's runs.
    robot, run_id : str, optional
        The run's robot and id in the archive (run id default: the folder's name).
    threshold_mm : float, optional
        Threshold drawn in the trend and used for its verdict.
    diagnose_if_missing : bool
        Run the diagnosis when the folder has no ``diagnosis.json``.

    Returns
    -------
    Report

    Raises
    ------
    InputError
        The folder has no ``model.json`` (nothing to report).
    """
    from quickhealth.identify.report import residual_plot, workspace_histogram
    from quickhealth.identify.workspace import all_joint_curves, workspace_error
    from quickhealth.station import formats

    from .archive import run_metadata

    d = Path(run_dir)
    if not (d / "model.json").is_file():
        raise InputError(f"{d}: no model.json (fit the run first: quickhealth identify fit)")
    fitted = formats.read_model(d / "model.json")
    meas = None
    if (d / "measurements.csv").is_file():
        meas = formats.read_measurements(d / "measurements.csv", fitted.robot.n_joints)
        if meas.n_poses != fitted.n_poses:
            meas = None  # not the data this model was fitted to
    meta = run_metadata(d)
    rid = run_id or meta.get("run_id") or d.resolve().name
    if archive is not None and robot is not None:  # the index knows what the folder may not
        rec = next((r for r in archive.runs(robot) if r.run_id == rid), None)
        if rec is not None:
            meta = {**meta, **{k: v for k, v in rec.meta.items() if v}, "time_utc": rec.time_utc}
    sections: list[Section] = []

    # 1. summary
    lines = [
        f"robot: {fitted.robot.name}" + (f" ({robot})" if robot else ""),
        f"errors against the nominal kinematics of {nominal_of(fitted.robot)}",
        f"run: {rid}" + (f", {meta['time_utc']}" if "time_utc" in meta else ""),
    ]
    for k in ("plan_hash", "cell", "calibration_id", "software_version"):
        lines.append(f"{k.replace('_', ' ')}: {meta.get(k, '(unknown)')}")
    lines += list(fitted.summary())
    sections.append(Section("summary", "Summary", tuple(lines), data={"meta": meta, "run_id": rid}))

    # 2. plan coverage
    plan = _json(d / "plan.json")
    q_plan = None
    if plan and isinstance(plan.get("poses"), list) and plan["poses"]:
        q_plan = np.radians(np.array([p["q_deg"] for p in plan["poses"]], dtype=float))
        src = "plan.json"
    elif meas is not None:
        q_plan, src = meas.q, "measurements.csv (executed poses)"
    if q_plan is not None:
        fig = _coverage_figure(fitted.robot, q_plan, fitted.spec.q_lo, fitted.spec.q_hi)
        span = np.ptp(q_plan, axis=0) / (fitted.spec.q_hi - fitted.spec.q_lo)
        sections.append(
            Section(
                "coverage",
                "Plan coverage (paper Fig. 6)",
                (
                    f"{q_plan.shape[0]} poses from {src}",
                    "share of each joint's modelled range spanned: "
                    + ", ".join(f"j{j + 1} {s:.0%}" for j, s in enumerate(span)),
                ),
                plots=(Plot("coverage", "Plan coverage", _png(fig)),),
                data={"n_poses": int(q_plan.shape[0]), "range_share": span.tolist()},
            )
        )
    else:
        sections.append(
            Section(
                "coverage",
                "Plan coverage (paper Fig. 6)",
                missing="no plan.json and no measurements.csv",
            )
        )

    # 3. workspace error
    ws = workspace_error(fitted, n_samples=workspace_samples)
    cond = ws.conditions.describe()
    sections.append(
        Section(
            "workspace",
            "Workspace TCP error (paper Fig. 7)",
            (
                f"mean {ws.mean * 1e3:.3f} mm, std {ws.std * 1e3:.3f} mm, "
                f"95 % {ws.p95 * 1e3:.3f} mm, max {ws.max * 1e3:.3f} mm "
                f"over {ws.n_samples} joint commands uniform in the modelled ranges"
                + (f", {cond}" if cond else ""),
            ),
            plots=(
                Plot("workspace_hist", "Workspace error histogram", _png(workspace_histogram(ws))),
            ),
            data=ws.as_dict(),
        )
    )

    # 4. joint curves
    curves = all_joint_curves(fitted, n_points=61)
    sections.append(
        Section(
            "curves",
            "Error motions of every joint, 95 % bands (paper Fig. 8)",
            ("bands: sampling uncertainty of the estimate; model error is not in them",),
            plots=tuple(
                Plot(f"curves_j{c.joint}", f"Joint {c.joint}", _png(joint_figure(c, fitted)))
                for c in curves
            ),
            data={"joint_curves": [c.as_dict() for c in curves]},
        )
    )

    # 5. residuals
    if meas is not None:
        sections.append(
            Section(
                "residuals",
                "Measured versus model",
                (f"rms position residual {fitted.rms_pos * 1e3:.4f} mm",),
                plots=(Plot("residuals", "Residuals", _png(residual_plot(fitted, meas))),),
                data={"rms_pos_mm": fitted.rms_pos * 1e3},
            )
        )
    else:
        sections.append(
            Section(
                "residuals",
                "Measured versus model",
                missing="measurements.csv missing or not the fitted data",
            )
        )

    # 6. diagnosis
    sections.append(_diagnosis_section(d, fitted, meas, diagnose_if_missing))

    # 7. trend
    trend_sec, trend_res = _trend_section(archive, robot, rid, threshold_mm)
    sections.append(trend_sec)

    # 8. ISO 9283
    sections.append(_iso_section(fitted, meas))

    # 0. the verdict, first
    diag_doc = next(s for s in sections if s.key == "diagnosis").data
    sections.insert(0, _verdict_section(ws, trend_res, diag_doc, threshold_mm, noise=fitted.noise))

    return Report(
        title=f"quickhealth report: {fitted.robot.name}, run {rid}",
        run_dir=str(d),
        sections=tuple(sections),
    )


VERDICTS = ("healthy", "degraded", "flagged")


def _finite(v: float, default: float) -> float:
    return float(v) if math.isfinite(v) else default


def _verdict_section(
    ws: Any, trend: Any, diag: dict[str, Any], threshold_mm: float | None, noise: Any = None
) -> Section:
    """Healthy, degraded or flagged, the one-line reason, the TCP error against the baseline
    and the top missing effect.

    flagged: the trend against the baseline raised a flag (a control-chart alarm, a
    threshold crossed, an error curve changed).  degraded: no flag, but the mean or max TCP
    error is more than 10 % above the baseline's, the run's figure is above the threshold,
    or the diagnosis finds a physical effect the model misses.  healthy: none of these.
    """
    mean, mx = ws.mean * 1e3, ws.max * 1e3
    data: dict[str, Any] = {"mean_mm": mean, "max_mm": mx, "conditions": ws.conditions.describe()}
    base_mean = base_max = None
    if trend is not None:  # both figures from the archive's index: like with like
        b, i = trend.baseline_index, trend.latest
        mean = _finite(trend.figures_mm["mean"][i], mean)
        mx = _finite(trend.figures_mm["max"][i], mx)
        data.update(mean_mm=mean, max_mm=mx)
        base_mean = trend.figures_mm["mean"][b]
        base_max = trend.figures_mm["max"][b]
        data.update(baseline_run=trend.run_ids[b], baseline_mean_mm=base_mean)
        data.update(baseline_max_mm=base_max, this_is_baseline=b == i)
    top = None
    if diag.get("verdict") == "missing-effect":
        sugg = diag.get("suggested") or []
        cands = {c.get("effect"): c for c in diag.get("candidates", [])}
        name = sugg[0] if sugg else next(iter(cands), None)
        if name is not None:
            top = {
                "effect": name,
                **{k: cands.get(name, {}).get(k) for k in ("predicted_rms_drop_mm",)},
            }
    data["top_missing_effect"] = top
    flags = trend.flags() if trend is not None else []
    rose = [
        f"{what} TCP error {now:.3f} mm is {now / base - 1:.0%} above the baseline's {base:.3f} mm"
        for what, now, base in (("mean", mean, base_mean), ("max", mx, base_max))
        if base is not None and base > 0 and now > 1.1 * base
    ]
    fig_now = {"mean": mean, "max": mx}.get(getattr(trend, "threshold_figure", "max"), mx)
    if flags:
        verdict, reason = (
            "flagged",
            flags[0] + (f" (and {len(flags) - 1} more)" if len(flags) > 1 else ""),
        )
    elif threshold_mm is not None and fig_now > threshold_mm:
        verdict, reason = (
            "degraded",
            f"TCP error {fig_now:.3f} mm is above the threshold {threshold_mm:g} mm",
        )
    elif rose:
        verdict, reason = "degraded", rose[0]
    elif top is not None:
        drop = top.get("predicted_rms_drop_mm")
        verdict = "degraded"
        reason = f"the error model misses a physical effect: {top['effect']}" + (
            f" (adding it would lower the residual RMS by {drop:.3f} mm)"
            if drop is not None
            else ""
        )
    else:
        verdict = "healthy"
        reason = (
            "no flag against the baseline and no missing effect"
            if trend is not None
            else "no missing effect (no baseline to compare with: the run is not archived)"
        )
    if noise is not None and noise.rescaled:  # say it where it is read first
        reason += (
            "; uncertainty estimated from the residuals (the stated instrument uncertainty was "
            f"too small: {noise.excess_pos * 1e3:.3g} mm added per axis)"
        )
    data.update(verdict=verdict, reason=reason)
    if base_mean is not None and base_max is not None:
        err = (
            f"TCP error: mean {mean:.3f} mm (baseline {base_mean:.3f} mm, {mean - base_mean:+.3f}), "
            f"max {mx:.3f} mm (baseline {base_max:.3f} mm, {mx - base_max:+.3f}) "
            f"against baseline run {data['baseline_run']}"
        )
    else:
        err = f"TCP error: mean {mean:.3f} mm, max {mx:.3f} mm (no baseline: run not archived)"
    if data["conditions"]:
        err += f"; {data['conditions']}"
    lines = [f"{verdict.upper()}: {reason}", err]
    lines.append(
        f"top missing effect: {top['effect']}" if top is not None else "top missing effect: none"
    )
    return Section("verdict", "Verdict", tuple(lines), data=data)


def _diagnosis_section(d: Path, fitted: Any, meas: Any, run_it: bool) -> Section:
    title = "Diagnosis: which physical effect is missing"
    doc = _json(d / "diagnosis.json")
    if doc is None and run_it and meas is not None:
        from quickhealth.identify.diagnose import diagnose, state_from_fitted

        doc = diagnose(state_from_fitted(fitted), meas).to_dict(top=8)
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
        data=doc,
        folded=tuple(small) if len(small) > 1 else (),
        folded_title=f"{len(small) - 1} candidates too small to matter or not significant",
    )


def _trend_section(
    archive: Any, robot: str | None, rid: str, threshold_mm: float | None
) -> tuple[Section, Any]:
    """The trend section and the trend result (None when there is no trend)."""
    title = "Trend against the baseline"
    if archive is None or robot is None:
        return Section(
            "trend", title, missing="run not archived: quickhealth archive add RUN_DIR --robot NAME"
        ), None
    from quickhealth.identify.errors import InputError
    from quickhealth.identify.trend import assess_trend
    from quickhealth.station.archive import missing_words, trend_runs

    if rid not in [r.run_id for r in archive.runs(robot)]:
        return Section(
            "trend", title, missing=f"run {rid} is not in the archive of robot {robot}"
        ), None
    try:  # runs whose archive folders are missing are left out, and said so
        recs, missing = trend_runs(archive, robot, upto=rid)
    except InputError as exc:
        return Section("trend", title, missing=str(exc)), None
    b = next((i for i, r in enumerate(recs) if r.baseline), None)
    if b is None:
        return Section(
            "trend", title, missing=f"robot {robot} has no baseline before this run"
        ), None
    states = [archive.run_state(r, like=recs[b]) for r in recs]
    res = assess_trend(states, b, threshold_mm=threshold_mm)
    flags = res.flags()
    lines = [
        f"{len(recs)} runs; baseline {recs[b].run_id}",
        "verdict: " + ("FLAGGED" if flags else "healthy"),
    ]
    lines += flags
    lines += [p.words() for p in res.prognoses.values()]
    lines += [f"warning: {w}" for w in [*missing_words(archive, missing), *res.warnings]]
    rows = [("run", "time (UTC)", "mean (mm)", "std (mm)", "max (mm)", "flags")]
    for i, r in enumerate(recs):
        rows.append(
            (
                r.run_id + (" (baseline)" if i == b else ""),
                r.time_utc,
                *(f"{res.figures_mm[f][i]:.3f}" for f in ("mean", "std", "max")),
                str(len(res.flags(i))),
            )
        )
    return Section(
        "trend",
        title,
        tuple(lines),
        table=tuple(rows),
        plots=(Plot("trend", "Trend", _png(trend_figure(res))),),
        data=trend_json(res),
    ), res


def _iso_section(fitted: Any, meas: Any) -> Section:
    title = "ISO 9283-style pose accuracy and repeatability"
    if meas is None or meas.pose_id is None:
        return Section(
            "iso9283", title, missing="no pose_id column: the plan has no repeated poses"
        )
    from quickhealth.identify.errormodel import constant_motions
    from quickhealth.identify.transforms import small_error_transform

    T_cmd = fitted.nominal_pose(meas.q)
    rot = meas.has_orientation
    m0 = constant_motions(fitted.spec, fitted.coeffs, 0)
    R_base = (fitted.T_instr_base0 @ small_error_transform(m0[:3], m0[3:]))[:3, :3]
    stats = iso9283_pose_stats(
        meas.pose_id,
        meas.pos,
        T_cmd[:, :3, 3],
        meas.R if rot else None,
        T_cmd[:, :3, :3] if rot else None,
        R_base,
    )
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

    def abc(v: Any, signed: bool) -> str:
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
        plots=(Plot("iso9283", "ISO 9283", _png(_iso_figure(stats))),),
        data={"orientation": rot, "poses": poses},
    )


def trend_json(res: Any) -> dict[str, Any]:
    """A TrendResult as JSON-able numbers (mm, s, words)."""
    return {
        "run_ids": list(res.run_ids),
        "t_s": list(res.t_s),
        "baseline": res.run_ids[res.baseline_index],
        "figures_mm": {k: list(v) for k, v in res.figures_mm.items()},
        "flags": res.flags(),
        "flagged": res.flagged,
        "hints": res.hints,
        "warnings": list(res.warnings),
        "threshold_mm": res.threshold_mm,
        "prognosis": {
            f: {
                "trend": p.trend,
                "slope_mm_per_day": p.slope_mm_per_day,
                "p_value": p.p_value,
                "crossing_t_s": p.crossing_t_s,
                "crossing_early_t_s": p.crossing_early_t_s,
                "crossing_late_t_s": p.crossing_late_t_s,
                "words": p.words(),
            }
            for f, p in res.prognoses.items()
        },
        "curve_changes": [
            {
                "joint": c.joint,
                "motion": c.motion,
                "max_change": c.max_change,
                "z_max": c.z_max,
                "p_value": c.p_value,
                "significant": c.significant,
            }
            for c in res.curve_changes[res.latest]
        ],
    }


# ------------------------------------------------------------------------ rendering


def report_json(rep: Report) -> dict[str, Any]:
    """The report's content as JSON-able data (sections with their numbers and text)."""
    return {
        "title": rep.title,
        "run_dir": rep.run_dir,
        "sections": {
            s.key: {
                "title": s.title,
                "lines": list(s.lines),
                "table": [list(r) for r in s.table],
                "plots": [p.key for p in s.plots],
                "missing": s.missing or None,
                "not_applicable": s.not_applicable or None,
                "data": s.data,
                "folded": [list(r) for r in s.folded],
            }
            for s in rep.sections
        },
    }


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
            cls = ' class="flag"' if line.startswith(("verdict: FLAGGED", "joint ")) else ""
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
    payload = json.dumps(_plain(report_json(rep))).replace("</", "<\\/")
    out.append(f'<script type="application/json" id="report-json">{payload}</script>')
    out.append("</body></html>")
    return "\n".join(out)
