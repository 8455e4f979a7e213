"""Monitoring commands: archive runs, watch the trend, act on the model, report, reprocess.

quickhealth archive add RUN_DIR --robot NAME [--run-id ID] [--time ISO] [--baseline] ...
quickhealth archive baseline ROBOT RUN_ID | ROBOT --clear
quickhealth archive list [ROBOT]
quickhealth trend ROBOT [--threshold-mm X] [--figure max] [--tolerance-mm X] [--json OUT] [--plot PNG]
    Exit 1 when the latest run is flagged: above the threshold, outside its control limits,
    or with an error curve that changed beyond the combined uncertainty (--fail-on threshold:
    only the threshold counts).
quickhealth export MODEL.json [--urdf OUT.urdf] [--ur-calibration OUT.yaml|OUT.conf] [--json OUT.json]
quickhealth compensate MODEL.json PROGRAM --out NEW_PROGRAM [--errors ERR.csv] [--tcp-mm X,Y,Z]
    [--temp-c C] [--time-s S] [--leave-out EFFECTS] [--max-correction-deg D]
quickhealth report RUN_DIR [--out report.html] [--archive DIR --robot NAME]
quickhealth reprocess [ROBOT] [--runs IDS] [--calibration CAL.json] [--scheduler ADDRESS] [--workers N]

Every command takes --archive DIR (default $QUICKHEALTH_ARCHIVE, else ~/quickhealth-archive)
and --db URL (an SQLAlchemy URL, e.g. postgresql+psycopg://host/db, for a shared index).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from quickhealth.station import lock, options, workers


def _archive_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--archive",
        default=None,
        help="archive folder (default $QUICKHEALTH_ARCHIVE, else ~/quickhealth-archive)",
    )
    p.add_argument("--db", default=None, help="SQLAlchemy URL of a shared index (default SQLite)")
    p.add_argument(
        "--db-timeout",
        type=options.TIMEOUT_S,
        default=None,
        help="seconds to connect to the index and for each index operation "
        "(default $QUICKHEALTH_DB_TIMEOUT, else 10)",
    )


def _open(args: argparse.Namespace, create: bool = False) -> Any:
    """The archive of ``--archive``/``--db``; only ``archive add`` creates a missing one."""
    from quickhealth.station.archive import Archive

    return Archive.open(args.archive, args.db, create=create, timeout_s=args.db_timeout)


def register(subparsers: Any) -> None:
    """Add ``archive``, ``trend``, ``export``, ``compensate``, ``report`` and ``reprocess``."""
    # ---- archive
    p = subparsers.add_parser("archive", help="archive runs; set a robot's baseline; list runs")
    sub = p.add_subparsers(dest="archive_command", metavar="SUBCOMMAND")
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])
    a = sub.add_parser("add", help="copy a run folder into the archive and index it")
    a.add_argument("run_dir")
    a.add_argument("--robot", required=True, help="robot name (letters, digits, . _ -)")
    a.add_argument("--run-id", default=None, help="default: the run's metadata or folder name")
    a.add_argument("--time", default=None, help="ISO 8601 UTC time of the run")
    for k in ("plan-hash", "cell", "calibration-id", "software-version"):
        a.add_argument(f"--{k}", default=None, help=f"override the run's {k.replace('-', ' ')}")
    h = a.add_mutually_exclusive_group()
    h.add_argument("--healthy", dest="healthy", action="store_const", const=True, default=None)
    h.add_argument("--unhealthy", dest="healthy", action="store_const", const=False)
    a.add_argument("--baseline", action="store_true", help="make this run the robot's baseline")
    _archive_args(a)
    a.set_defaults(func=_archive_add)
    b = sub.add_parser("baseline", help="set (or --clear) a robot's baseline run")
    b.add_argument("robot")
    b.add_argument("run_id", nargs="?")
    b.add_argument("--clear", action="store_true", help="back to the first healthy run")
    _archive_args(b)
    b.set_defaults(func=_archive_baseline)
    ls = sub.add_parser("list", help="robots, or one robot's runs")
    ls.add_argument("robot", nargs="?")
    _archive_args(ls)
    ls.set_defaults(func=_archive_list)

    # ---- trend
    t = subparsers.add_parser(
        "trend",
        help="a robot's runs over time against its baseline; exit 1 when flagged",
        description=(
            "Workspace error figures, error-curve changes judged against the combined "
            "uncertainty, EWMA control limits, prognosis and root-cause hints. Exit status 1 "
            "when the latest run is flagged."
        ),
    )
    t.add_argument("robot")
    _archive_args(t)
    t.add_argument(
        "--threshold-mm", type=options.LENGTH_MM, default=None, help="flag a run above this"
    )
    t.add_argument(
        "--figure",
        choices=("mean", "std", "max"),
        default="max",
        help="figure the threshold applies to (max)",
    )
    t.add_argument(
        "--tolerance-mm",
        type=options.LENGTH_MM,
        default=None,
        help="level the prognosis extrapolates to (default: the threshold)",
    )
    t.add_argument(
        "--alpha",
        type=options.PROBABILITY,
        default=1e-4,
        help="false-alarm probability of the curve test per run (1e-4)",
    )
    t.add_argument(
        "--min-change-mm",
        type=options.CHANGE_MM,
        default=0.01,
        help="smallest translation change that counts (0.01)",
    )
    t.add_argument(
        "--min-change-mrad",
        type=options.CHANGE_MRAD,
        default=0.02,
        help="smallest rotation change that counts (0.02)",
    )
    t.add_argument(
        "--fail-on",
        choices=("any", "threshold"),
        default="any",
        help="what makes the exit status 1 (any flag)",
    )
    t.add_argument("--json", default=None, help="write the trend as JSON here")
    t.add_argument("--plot", default=None, help="write the trend figure (PNG) here")
    t.set_defaults(func=_trend)

    # ---- export
    e = subparsers.add_parser("export", help="corrected URDF and UR-style DH deltas from a model")
    e.add_argument("model", help="model.json")
    e.add_argument("--urdf", default=None, help="corrected URDF (joint origins) to write")
    e.add_argument(
        "--ur-calibration",
        default=None,
        help="OUT.yaml: the corrected kinematics as the UR ROS driver's calibration YAML; "
        "any other name: UR-style DH deltas (calibration.conf layout)",
    )
    e.add_argument("--json", default=None, help="the deltas and residuals as JSON")
    e.set_defaults(func=_export)

    # ---- compensate
    c = subparsers.add_parser(
        "compensate", help="rewrite a program's joint targets so the modelled TCP hits them"
    )
    c.add_argument("model", help="model.json")
    c.add_argument("program", help="URScript (.script) or CSV of joint columns q1..qN (deg)")
    c.add_argument("--out", required=True, help="the compensated program")
    c.add_argument("--errors", default=None, help="CSV of predicted error per target")
    c.add_argument("--tcp-mm", default="0,0,0", help="tool centre point on the flange, mm")
    c.add_argument(
        "--max-correction-deg",
        type=float,
        default=1.0,
        help="largest change of any joint of any target (1.0); a larger one is refused",
    )
    c.add_argument(
        "--temp-c",
        type=float,
        default=None,
        help="temperature the program runs at (needed by a model with 'thermal')",
    )
    c.add_argument(
        "--time-s",
        type=float,
        default=None,
        help="time the program runs at, s on the fitted run's clock (needed by 'drift')",
    )
    c.add_argument(
        "--leave-out",
        default=None,
        help="comma-separated effects of the model not to compensate (e.g. drift)",
    )
    c.set_defaults(func=_compensate)

    # ---- report
    r = subparsers.add_parser("report", help="the run's self-contained HTML report")
    r.add_argument("run_dir")
    r.add_argument("--out", default=None, help="HTML file (default RUN_DIR/report.html)")
    r.add_argument("--robot", default=None, help="the robot in the archive (trend section)")
    r.add_argument("--run-id", default=None, help="the run's id in the archive")
    r.add_argument("--threshold-mm", type=options.LENGTH_MM, default=None)
    r.add_argument("--no-diagnose", action="store_true", help="skip the diagnosis if missing")
    _archive_args(r)
    r.set_defaults(func=_report)

    # ---- reprocess
    rp = subparsers.add_parser(
        "reprocess", help="refit (and re-detect) archived runs, in parallel or on Dask"
    )
    rp.add_argument("robot", nargs="?", help="default: every robot")
    _archive_args(rp)
    rp.add_argument("--runs", default=None, help="comma-separated run ids (default all)")
    rp.add_argument("--calibration", default=None, help="new camera calibration: re-detect")
    rp.add_argument("--orders", choices=("keep", "select"), default="keep")
    rp.add_argument("--max-order", type=options.ORDER, default=6)
    rp.add_argument("--tag", default="reprocessed", help="output folder name in each run")
    rp.add_argument("--scheduler", default=None, help="Dask scheduler address (tcp://host:8786)")
    rp.add_argument(
        "--scheduler-timeout",
        type=options.TIMEOUT_S,
        default=10.0,
        help="seconds to reach the scheduler and find a worker (10)",
    )
    rp.add_argument(
        "--workers", type=options.WORKERS, default=None, help="local processes (CPU count)"
    )
    rp.add_argument("--workspace-samples", type=options.SAMPLES, default=5000)
    rp.add_argument(
        "--update-index",
        action="store_true",
        help="replace the indexed figures with the reprocessed ones",
    )
    rp.set_defaults(func=_reprocess)


# ------------------------------------------------------------------------- archive


def _archive_add(args: argparse.Namespace) -> int:
    from quickhealth.station.archive import prepare_run

    meta = {
        k: v
        for k, v in (
            ("plan_hash", args.plan_hash),
            ("cell", args.cell),
            ("calibration_id", args.calibration_id),
            ("software_version", args.software_version),
        )
        if v is not None
    }
    # the run is checked before the archive is opened: a refused run creates nothing
    prep = prepare_run(
        args.robot,
        args.run_dir,
        run_id=args.run_id,
        time_utc=args.time,
        meta=meta,
        healthy=args.healthy,
    )
    arch = _open(args, create=True)
    try:
        rec = arch.add_prepared(prep)
    except BaseException:
        arch.undo_creation()
        raise
    if args.baseline:
        arch.set_baseline(rec.robot, rec.run_id)
    print(f"archived {rec.robot}/{rec.run_id} ({rec.time_utc}) in {arch.folder(rec)}")
    return 0


def _archive_baseline(args: argparse.Namespace) -> int:
    from quickhealth.identify.errors import InputError

    arch = _open(args)
    if args.clear == (args.run_id is not None):
        raise InputError("give either a RUN_ID or --clear")
    arch.set_baseline(args.robot, None if args.clear else args.run_id)
    b = arch.baseline(args.robot)
    print(f"baseline of {args.robot}: {b.run_id if b else '(none)'}")
    return 0


def _archive_list(args: argparse.Namespace) -> int:
    arch = _open(args)
    if args.robot is None:
        for last, n, b in arch.fleet():  # three index queries, however large the fleet
            print(f"{last.robot}: {n} runs, baseline {b or '-'}, latest {last.run_id}")
        return 0
    print(
        f"{'run':<24} {'time (UTC)':<21} {'mean':>7} {'std':>7} {'max':>7}  plan / cell / calibration"
    )
    for x in arch.runs(args.robot):
        mark = "*" if x.baseline else " "
        print(
            f"{mark}{x.run_id:<23} {x.time_utc:<21} {x.mean_mm:7.3f} {x.std_mm:7.3f} "
            f"{x.max_mm:7.3f}  {x.plan_hash[:12]} / {x.cell} / {x.calibration_id}"
        )
    return 0


# --------------------------------------------------------------------------- trend


def _trend(args: argparse.Namespace) -> int:
    from quickhealth.identify.errors import InputError
    from quickhealth.station.report_html import trend_figure, trend_json

    for name in ("threshold_mm", "tolerance_mm"):
        v = getattr(args, name)
        if v is not None and not v > 0:
            raise InputError(f"--{name.replace('_', '-')} must be > 0, got {v}")
    if not 0 < args.alpha < 1:
        raise InputError(f"--alpha must be in (0, 1), got {args.alpha}")
    from quickhealth.station.archive import missing_words, trend_for, trend_runs
    from quickhealth.station.fsio import refuse_outputs_inside, refuse_overwriting_inputs

    refuse_overwriting_inputs([("--json", args.json), ("--plot", args.plot)], [])
    arch = _open(args)
    # the archive (its index, its run folders) is this command's input
    refuse_outputs_inside([("--json", args.json), ("--plot", args.plot)], arch.root, "the archive")
    res = trend_for(
        arch,
        args.robot,
        threshold_mm=args.threshold_mm,
        threshold_figure=args.figure,
        tolerance_mm=args.tolerance_mm,
        alpha=args.alpha,
        min_change_m=args.min_change_mm * 1e-3,
        min_change_rad=args.min_change_mrad * 1e-3,
    )
    recs, missing = trend_runs(arch, args.robot)  # the runs trend_for judged
    print(f"{args.robot}: {len(recs)} runs, baseline {res.run_ids[res.baseline_index]}")
    print(f"  {'run':<24} {'time (UTC)':<21} {'mean':>7} {'std':>7} {'max':>7}  verdict")
    for i, r in enumerate(recs):
        v = (
            "baseline"
            if i == res.baseline_index
            else ("-" if i < res.baseline_index else ("FLAGGED" if res.flags(i) else "ok"))
        )
        f = res.figures_mm
        print(
            f"  {r.run_id:<24} {r.time_utc:<21} {f['mean'][i]:7.3f} {f['std'][i]:7.3f} "
            f"{f['max'][i]:7.3f}  {v}"
        )
    for w in [*missing_words(arch, missing), *res.warnings]:
        print(f"warning: {w}")
    flags = res.flags()
    print(f"latest run {res.run_ids[-1]}: " + ("FLAGGED" if flags else "healthy"))
    for line in flags:
        print(f"  - {line}")
    for p in res.prognoses.values():
        print(f"prognosis: {p.words()}")
    if args.json:
        from quickhealth.station.formats import write_text_atomic

        write_text_atomic(args.json, json.dumps(_plain(trend_json(res)), indent=1) + "\n")
    if args.plot:
        from quickhealth.station.fsio import write_figure

        write_figure(trend_figure(res), args.plot, dpi=100)
    if args.fail_on == "threshold":
        return 1 if res.breaches[-1] else 0
    return 1 if flags else 0


def _plain(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


# ------------------------------------------------------------------ export, compensate


def _export(args: argparse.Namespace) -> int:
    from quickhealth.identify.compensate import (
        corrected_robot,
        dh_deltas,
        export_notes,
        ur_calibration_text,
        ur_kinematics_text,
        urdf_text,
    )
    from quickhealth.identify.errors import InputError
    from quickhealth.station.formats import read_model, write_text_atomic
    from quickhealth.station.fsio import refuse_overwriting_inputs

    if not (args.urdf or args.ur_calibration or args.json):
        raise InputError("nothing to export: give --urdf, --ur-calibration and/or --json")
    refuse_overwriting_inputs(
        [("--urdf", args.urdf), ("--ur-calibration", args.ur_calibration), ("--json", args.json)],
        [args.model],
    )
    import numpy as np

    fm = read_model(args.model)  # validated: finite, sane coefficients (never a URDF of "nan")
    notes = export_notes([e.name for e in fm.effects])
    # every document is computed before the first is written: no half export on a failure
    docs: list[tuple[str, str, str]] = []
    if args.urdf:
        rc = corrected_robot(fm.robot, fm.spec, fm.coeffs)
        if not np.all(np.isfinite(rc.links)):
            raise InputError(f"{args.model}: the corrected kinematics are not finite")
        docs.append(
            (
                args.urdf,
                urdf_text(rc, comments=notes),
                "joint origins with the identified constant joint errors",
            )
        )
    as_yaml = bool(args.ur_calibration) and Path(args.ur_calibration).suffix.lower() in (
        ".yaml",
        ".yml",
    )
    if as_yaml:
        try:
            text, kex = ur_kinematics_text(fm.robot, fm.spec, fm.coeffs, notes)
        except ValueError as exc:
            raise InputError(f"{args.model}: {exc}") from None
        if not np.all(np.isfinite(kex.kinematics.xyz)) or not np.all(
            np.isfinite(kex.kinematics.rpy)
        ):
            raise InputError(f"{args.model}: the corrected kinematics are not finite")
        docs.append((args.ur_calibration, text, "corrected kinematics, UR ROS driver YAML"))
    if (args.ur_calibration and not as_yaml) or args.json:
        try:
            cal = dh_deltas(fm.robot, fm.spec, fm.coeffs)
        except ValueError as exc:
            hint = ""
            if fm.robot.nominal is not None and fm.robot.nominal.calibration is not None:
                hint = (
                    f" (fitted against the controller calibration {fm.robot.nominal.calibration}:"
                    " export --ur-calibration OUT.yaml instead)"
                )
            raise InputError(f"{args.model}: {exc}{hint}") from None
        print(
            f"DH deltas: corrected kinematics differ from nominal by "
            f"{cal.nominal_residual_pos_rms * 1e3:.4f} mm rms; DH cannot express "
            f"{cal.residual_pos_rms * 1e3:.4f} mm rms of it"
        )
        if args.ur_calibration and not as_yaml:
            docs.append(
                (args.ur_calibration, ur_calibration_text(cal, notes), "UR-style DH deltas")
            )
        if args.json:
            doc = {
                "units": "m, rad",
                "effects_left_out": [e.name for e in fm.effects],
                "delta_theta": cal.delta_theta.tolist(),
                "delta_a": cal.delta_a.tolist(),
                "delta_d": cal.delta_d.tolist(),
                "delta_alpha": cal.delta_alpha.tolist(),
                "residual_pos_rms_mm": cal.residual_pos_rms * 1e3,
                "residual_rot_rms_mrad": cal.residual_rot_rms * 1e3,
            }
            docs.append((args.json, json.dumps(doc, indent=1, allow_nan=False) + "\n", "deltas"))
    if fm.effects:
        print(notes[0])
    for path, text, what in docs:
        write_text_atomic(path, text)
        print(f"wrote {path} ({what})")
    return 0


def _compensate(args: argparse.Namespace) -> int:
    """Compensate a program; refuse (exit 2, nothing written) anything that could make it worse.

    Refused, one line per target: a target outside the robot's joint limits or outside the
    joint range the model was identified on (the series would extrapolate), a compensated
    target outside the joint limits, a correction above ``--max-correction-deg`` on any joint,
    a target whose compensation did not converge, a target where the correction flips the
    direction the program moves a backlash joint in.  Refused as a whole: a model with
    ``thermal`` / ``drift`` without ``--temp-c`` / ``--time-s`` (or ``--leave-out``).
    """
    import numpy as np

    from quickhealth.identify.compensate import compensate_program
    from quickhealth.identify.effects.backlash import Backlash
    from quickhealth.identify.errors import InputError
    from quickhealth.identify.urscript import replace_targets
    from quickhealth.station import formats
    from quickhealth.station.formats.common import findings
    from quickhealth.station.fsio import refuse_overwriting_inputs

    cap = args.max_correction_deg
    if not 0 < cap <= 10:
        raise InputError(f"--max-correction-deg must be in (0, 10], got {cap}")
    if args.temp_c is not None and not -40.0 <= args.temp_c <= 100.0:
        raise InputError(f"--temp-c must be a temperature in [-40, 100] degC, got {args.temp_c}")
    if args.time_s is not None and not 0.0 <= args.time_s <= 1e7:
        raise InputError(f"--time-s must be in [0, 1e7] s, got {args.time_s}")
    refuse_overwriting_inputs(
        [("--out", args.out), ("--errors", args.errors)], [args.model, args.program]
    )
    fm = formats.read_model(args.model)
    nj = fm.robot.n_joints
    leave_out = [x.strip() for x in (args.leave_out or "").split(",") if x.strip()]
    needs = {
        col: [e.name for e in fm.effects if col in e.requires() and e.name not in leave_out]
        for col in ("temp", "time")
    }
    if needs["temp"] and args.temp_c is None:
        raise InputError(
            f"{args.model}: the model has {needs['temp'][0]!r}: give the temperature the "
            "program runs at with --temp-c (its link lengths refer to 20 degC), or leave it "
            f"out with --leave-out {needs['temp'][0]}; nothing written"
        )
    if needs["time"] and args.time_s is None:
        end = fm.reference_time
        ran = f"; the fitted run ended at {end:g} s" if end is not None else ""
        raise InputError(
            f"{args.model}: the model has {needs['time'][0]!r} (the robot base moving against "
            "the instrument): give the time the program runs at, on the fitted run's clock, "
            f"with --time-s{ran}; or --leave-out {needs['time'][0]} if the instrument moved, "
            "not the robot; nothing written"
        )
    try:
        tcp = np.array([float(v) for v in args.tcp_mm.split(",")]) * 1e-3
    except ValueError:
        raise InputError(f"--tcp-mm must be X,Y,Z in mm, got {args.tcp_mm!r}") from None
    if tcp.shape != (3,) or not np.all(np.isfinite(tcp)) or np.abs(tcp).max() > 2.0:
        raise InputError(f"--tcp-mm must be X,Y,Z in mm (finite, within 2000), got {args.tcp_mm!r}")
    T_tcp = np.eye(4)
    T_tcp[:3, 3] = tcp
    prog = Path(args.program)
    is_script = prog.suffix.lower() in (".script", ".urscript", ".urp")
    if is_script:
        text, targets = formats.read_urscript(prog, nj)
        q = targets.q
        where = [f"{prog}:{ln}: target {k + 1}" for k, ln in enumerate(targets.lines)]
    else:
        meas = formats.read_measurements(prog, nj, joints_only=True)
        q = meas.q
        where = [f"{prog}: target {k + 1}" for k in range(len(q))]
    lo, hi = fm.robot.q_min, fm.robot.q_max
    problems: list[str] = []
    for k in range(len(q)):
        for j in range(nj):
            v = q[k, j]
            if not lo[j] <= v <= hi[j]:
                problems.append(
                    f"{where[k]}: joint {j + 1} at {np.degrees(v):.6g} deg is outside the "
                    f"robot's limits [{np.degrees(lo[j]):.6g}, {np.degrees(hi[j]):.6g}] deg"
                )
            elif not fm.spec.q_lo[j] - 1e-9 <= v <= fm.spec.q_hi[j] + 1e-9:
                problems.append(
                    f"{where[k]}: joint {j + 1} at {np.degrees(v):.6g} deg is outside the range "
                    f"the model was identified on [{np.degrees(fm.spec.q_lo[j]):.6g}, "
                    f"{np.degrees(fm.spec.q_hi[j]):.6g}] deg: the model would extrapolate"
                )
    if problems:
        raise findings([f"{x}; nothing written" for x in problems])
    comp = compensate_program(
        fm, q, T_tcp, temp_c=args.temp_c, time_s=args.time_s, leave_out=leave_out
    )
    dq = np.degrees(comp.q - q)
    settled = comp.approach_settled if comp.approach_settled is not None else np.ones(len(q), bool)
    for k in range(len(q)):
        if not np.all(np.isfinite(comp.q[k])) or not comp.converged[k]:
            problems.append(f"{where[k]}: compensation did not converge (near a singularity?)")
            continue
        if not settled[k]:
            problems.append(
                f"{where[k]}: the correction reverses the direction the program moves a "
                "backlash joint into this target (the move is smaller than the correction): "
                "the side the gear rests on is undefined"
            )
        j = int(np.argmax(np.abs(dq[k])))
        if abs(dq[k, j]) > cap:
            problems.append(
                f"{where[k]}: joint {j + 1} correction {dq[k, j]:+.4g} deg exceeds "
                f"--max-correction-deg {cap:g}"
            )
        out_of = np.flatnonzero((comp.q[k] < lo) | (comp.q[k] > hi))
        if out_of.size:
            j = int(out_of[0])
            problems.append(
                f"{where[k]}: compensated joint {j + 1} at {np.degrees(comp.q[k, j]):.6g} deg "
                "is outside the robot's limits"
            )
    if problems:
        raise findings([f"{x}; nothing written" for x in problems])
    if is_script:
        new_text = replace_targets(text, targets.spans, comp.q)
    else:
        lines = [",".join(f"q{j + 1}" for j in range(nj))]
        lines += [",".join(f"{v:.9f}" for v in np.degrees(row)) for row in comp.q]
        new_text = "\n".join(lines) + "\n"
    rows = None
    if args.errors:
        rows = ["target,err_before_mm,err_after_mm,rot_after_mrad,max_dq_deg,converged"]
        adq = np.abs(dq).max(axis=1)
        for i in range(len(q)):
            rows.append(
                f"{i + 1},{comp.error_before_pos[i] * 1e3:.6f},{comp.residual_pos[i] * 1e3:.6f},"
                f"{comp.residual_rot[i] * 1e3:.6f},{adq[i]:.6f},{int(comp.converged[i])}"
            )
    formats.write_text_atomic(args.out, new_text)
    if rows is not None:
        formats.write_text_atomic(args.errors, "\n".join(rows) + "\n")
    print(
        f"{len(q)} targets: predicted TCP error {comp.error_before_pos.mean() * 1e3:.4f} mm mean "
        f"({comp.error_before_pos.max() * 1e3:.4f} max) before, "
        f"{comp.residual_pos.max() * 1e3:.6f} mm max after compensation; largest correction "
        f"{np.abs(dq).max():.4f} deg (cap {cap:g})"
    )
    for line in _compensation_notes(fm, comp, args, Backlash):
        print(line)
    print(f"wrote {args.out}" + (f", {args.errors}" if args.errors else ""))
    return 0


def _compensation_notes(fm: Any, comp: Any, args: argparse.Namespace, backlash: type) -> list[str]:
    """The lines that say what the compensation used and what it left out (never silently)."""
    import numpy as np

    out = []
    if comp.described:
        out.append("compensated effects: " + "; ".join(comp.described))
    for name, why in comp.left_out:
        out.append(f"left out: {name} ({why})")
    uses = {col for e in fm.effects if e.name in comp.effects for col in e.requires()}
    if args.temp_c is not None and "temp" not in uses:
        out.append(f"--temp-c {args.temp_c:g} not used: no compensated effect depends on it")
    if args.time_s is not None and "time" not in uses:
        out.append(f"--time-s {args.time_s:g} not used: no compensated effect depends on it")
    end = fm.reference_time
    if "time" in uses and end is not None and args.time_s > end:
        out.append(
            f"drift extrapolated linearly to {args.time_s:g} s; the fitted run ended at {end:g} s"
        )
    # a move smaller than the play leaves a real gear between its two sides
    for e, p in zip(fm.effects, fm.effect_params, strict=True):
        if not isinstance(e, backlash) or e.name not in comp.effects:
            continue
        out.append(
            f"note: {e.name}: the first target counts as reached with joint {e.joint + 1} "
            "moving in the positive direction (the fit's rule for a first pose); make the "
            "move into it do so"
        )
        step = np.abs(np.diff(comp.q[:, e.joint], prepend=comp.q[0, e.joint]))[1:]
        small = np.flatnonzero(step < abs(float(p[0])))
        if small.size:
            shown = ", ".join(str(int(k) + 2) for k in small[:8]) + (" …" if small.size > 8 else "")
            out.append(
                f"note: joint {e.joint + 1} moves less than its play "
                f"({np.degrees(abs(float(p[0]))):.4g} deg) into target(s) {shown}: the side "
                f"its gear rests on there is uncertain; {e.name} assumes the direction of the move"
            )
    return out


# -------------------------------------------------------------------------- report


@lock.holds_outputs("report", lambda a: [a.run_dir, a.out])
def _report(args: argparse.Namespace) -> int:
    """The run's HTML report; report.json gains the report's sections, keeping its schema.

    Refused (one line, exit 2, nothing written): a folder without model.json or report.json
    (fit it first), a report.json that is not a complete fit report of its schema, an --out
    that is one of the files the report reads.
    """
    from quickhealth.identify.errors import InputError
    from quickhealth.station import formats
    from quickhealth.station.fsio import refuse_overwriting_inputs, write_atomic
    from quickhealth.station.report_html import build_report, render_html, report_json
    from quickhealth.station.report_json import with_sections

    d = Path(args.run_dir)
    if not d.is_dir():
        raise InputError(f"{d}: not a run folder")
    fit_first = (
        f"fit the run first: quickhealth identify fit {d / 'measurements.csv'} --robot ROBOT "
        f"--out {d}"
    )
    for name in ("model.json", "report.json"):
        if not (d / name).is_file():
            raise InputError(f"{d}: no {name} ({fit_first})")
    out = Path(args.out) if args.out else d / "report.html"
    reads = ("model.json", "report.json", "measurements.csv", "plan.json", "run.json")
    reads += ("diagnosis.json", "journal.jsonl")
    refuse_overwriting_inputs([("--out", out)], [d / n for n in reads if (d / n).exists()])
    rp = d / "report.json"
    doc = formats.read_report(rp)  # a quickhealth report of a schema this version reads
    formats.check_report(doc, str(rp), complete=False)  # the fit's figures are there
    if doc["schema"] == formats.REPORT_SCHEMA:  # every key of /2, or it is not a /2 file
        try:
            formats.check_report(doc, str(rp))
        except InputError as exc:
            raise InputError(f"{exc}: not a complete report.json ({fit_first})") from None
    arch, robot = (_open(args), args.robot) if args.robot else _archived_as(args, d)
    rep = build_report(
        d,
        archive=arch,
        robot=robot,
        run_id=args.run_id,
        threshold_mm=args.threshold_mm,
        diagnose_if_missing=not args.no_diagnose,
    )
    page = render_html(rep)
    sections = report_json(rep)["sections"]
    new = with_sections(
        doc, {k: sections[k] for k in ("coverage", "diagnosis", "trend", "iso9283")}
    )
    formats.write_text_atomic(out, page)
    write_atomic(rp, new)
    print(f"wrote {out} ({len(rep.plots)} plots) and updated {rp}")
    return 0


def _archived_as(args: argparse.Namespace, d: Path) -> tuple[Any, str | None]:
    """The archive and robot under which run folder ``d`` was archived (``archive add``), if
    it was: a run of the folder's run id whose archived model.json is this folder's, under one
    robot only.  An archive that does not exist is not created."""
    from quickhealth.station.archive import Archive, NoArchive, default_root, run_metadata

    root = Path(args.archive) if args.archive else default_root()
    if args.db is None and not (root / "index.sqlite").is_file():
        return None, None
    try:
        arch = Archive.open(root, args.db, create=False, timeout_s=args.db_timeout)
    except NoArchive:
        return None, None
    rid = args.run_id or run_metadata(d).get("run_id") or d.resolve().name
    model = (d / "model.json").read_bytes()
    found, refitted = [], []
    for robot in arch.robots():
        for rec in arch.runs(robot):
            if rec.run_id == rid:
                mp = arch.folder(rec) / "model.json"
                same = mp.is_file() and mp.read_bytes() == model
                (found if same else refitted).append(robot)
    if len(found) != 1:
        if not found and refitted:
            print(
                f"note: run {rid} of robot {', '.join(refitted)} in the archive {arch.root} has "
                f"another model.json than {d} (refitted since archive add?): no trend section; "
                "give --robot to report against it anyway"
            )
        return None, None
    print(f"{d} is run {rid} of robot {found[0]} in the archive {arch.root}")
    return arch, found[0]


# ------------------------------------------------------------------------ reprocess


@workers.owns_workers
def _reprocess(args: argparse.Namespace) -> int:
    import time

    from quickhealth.identify.errors import InputError
    from quickhealth.station.reprocess import check_scheduler, jobs_for_archive, reprocess

    if args.scheduler is not None:
        check_scheduler(args.scheduler)
    arch = _open(args)
    runs = None if args.runs is None else [r.strip() for r in args.runs.split(",") if r.strip()]
    jobs = jobs_for_archive(
        arch,
        args.robot,
        run_ids=runs,
        tag=args.tag,
        calibration=args.calibration,
        orders=args.orders,
        max_order=args.max_order,
        workspace_samples=args.workspace_samples,
    )
    if args.scheduler_timeout <= 0:
        raise InputError(f"--scheduler-timeout must be > 0, got {args.scheduler_timeout}")
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else "local processes"
    print(f"reprocessing {len(jobs)} runs on {where}", file=sys.stderr, flush=True)
    t0 = time.monotonic()

    def progress(k: int, n: int, r: Any) -> None:
        el = time.monotonic() - t0
        left = el / k * (n - k)
        print(
            f"  [{k}/{n}] {r.robot}/{r.run_id} {'ok' if r.ok else 'FAILED'} "
            f"({el:.0f} s, about {left:.0f} s left)",
            file=sys.stderr,
            flush=True,
        )

    results = reprocess(
        jobs,
        scheduler=args.scheduler,
        workers=args.workers,
        progress=progress,
        scheduler_timeout_s=args.scheduler_timeout,
    )
    for r in results:
        print(r.line())
        if r.ok and args.update_index:
            arch.update_figures(r.robot, r.run_id, r.figures_mm)
    failed = sum(not r.ok for r in results)
    if failed:
        print(f"{failed} of {len(results)} runs failed", file=sys.stderr)
        return 3
    return 0
