"""``quickhealth identify``: fit the error model to measurements, predict new commands.

quickhealth identify fit MEAS.csv --robot ROBOT [--calibration CAL.yaml] [--cell CELL]
    --out DIR [--effects LIST] [--max-order N]
    [--sigma-pos-mm S] [--sigma-rot-deg S] [--sigma-q-deg S] [--plots] [--auto-rescale]
quickhealth identify predict DIR/model.json INPUT --out PRED.csv [--threshold-mm T]
    INPUT: a measurement CSV, a CSV of joint columns only, or a URScript file (.script)
    whose movej/movel joint targets are predicted.  Exit 1 if --threshold-mm is given and
    some command's predicted error exceeds it.
quickhealth identify import-wam WAM.csv --out MEAS.csv [--sign auto|+1|-1] [--robot R]
    Converts the Barrett WAM laser-tracker files to CSV v1.
quickhealth identify compare DIR/model.json MEAS.csv --effects LIST [--heldout HELD.csv]
    [--folds K] [--json OUT.json] [--plots DIR]
    Held-out error without and with the effects (:mod:`.compare`; the same command as the
    top-level ``quickhealth compare``).

``identify fit`` is :func:`quickhealth.station.services.fitting.fit_folder` with the options
of the command line (the TUI's Results screen and ``reprocess`` fit the same way).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import math
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from ...identify.fit import FittedModel
from ...identify.linearize import InstrumentNoise
from ...identify.measurements import Measurements
from ...identify.robot import BUILTIN_ROBOTS, RobotModel
from ...identify.transforms import R_to_rpy
from ...identify.workspace import (
    CommandPrediction,
    Conditions,
    predict_commands,
    prediction_band,
)
from .. import formats, options, workers
from ..fsio import claim_output_folder, refuse_overwriting_inputs
from ..planning.cell import load_cell
from ..progress import Progress
from ..reporting.verdict import Spec, ThresholdFigure, spec_of_meta
from ..run import lock
from ..services.fitting import FigureRenderer, claim_fit_folder, fit_folder
from ..services.options import FitOptions
from ..services.wam import wam_sign
from . import compare

F = NDArray[np.float64]

# every door's instrument defaults (0.03 mm, 0.1 mrad), in the command line's units (help);
# an option left out keeps the default itself, not its round trip through mm and degrees
DEFAULT_SIGMA_POS_MM = FitOptions().noise.sigma_pos * 1e3
DEFAULT_SIGMA_ROT_DEG = math.degrees(FitOptions().noise.sigma_rot)


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``identify fit``, ``identify predict``, ``identify import-wam`` and ``identify compare``."""
    p = subparsers.add_parser("identify", help="fit the error model; predict new commands")
    sub = p.add_subparsers(dest="identify_command", metavar="SUBCOMMAND")
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])

    f = sub.add_parser(
        "fit",
        help="fit the error model (BIC order search) and write model.json, report.json",
        description="Implicit-loop ML fit of the paper's error model with BIC order selection.",
    )
    f.add_argument("meas", help="measurement file, CSV v1")
    f.add_argument(
        "--robot", required=True, help="built-in name (ur3 … ur30, ur10e) or .toml/.urdf file"
    )
    f.add_argument(
        "--calibration",
        default=None,
        help="the controller's calibration (UR ROS driver kinematics YAML) as nominal kinematics",
    )
    f.add_argument(
        "--cell",
        default=None,
        help="the cell the data were measured in (file or built-in name): the robot carries "
        "its smart target ([target] mass_kg), so gravity compliance uses both masses",
    )
    f.add_argument("--out", required=True, help="output directory")
    f.add_argument("--effects", default=None, help="comma-separated effect names")
    f.add_argument(
        "--max-order",
        type=options.ORDER,
        default=FitOptions.max_order,
        help=f"cap of every series' order ({FitOptions.max_order})",
    )
    f.add_argument(
        "--sigma-pos-mm",
        type=options.SIGMA_POS_MM,
        default=None,
        help=f"instrument position uncertainty per axis where the file has no sx..sz ({DEFAULT_SIGMA_POS_MM:.4g})",
    )
    f.add_argument(
        "--sigma-rot-deg",
        type=options.SIGMA_ROT_DEG,
        default=None,
        help=f"instrument orientation noise per rotation axis where the file has no spitch.. ({DEFAULT_SIGMA_ROT_DEG:.4g})",
    )
    f.add_argument(
        "--sigma-q-deg", type=options.SIGMA_Q_DEG, default=0.0, help="joint encoder uncertainty (0)"
    )
    f.add_argument(
        "--margin", type=options.MARGIN, default=None, help="BIC drop a raise must reach"
    )
    f.add_argument(
        "--auto-rescale",
        action="store_true",
        help="rerun once with the suspected uncertainty raised if the chi2 check fails",
    )
    f.add_argument(
        "--spec-mm",
        type=options.LENGTH_MM,
        default=None,
        help="the accuracy spec: the TCP error (mm, workspace maximum) the application "
        "accepts, recorded in report.json for every verdict (default: the --cell's, the "
        "robot file's or the run's spec_mm)",
    )
    f.add_argument("--plots", action="store_true", help="also write PNG figures into DIR")
    f.add_argument(
        "--force",
        action="store_true",
        help="write into DIR even if it holds a plan, another run or the fit of other data",
    )
    f.add_argument("--quiet", action="store_true", help="no progress on stderr")
    f.set_defaults(func=_fit)

    pr = sub.add_parser("predict", help="predict poses and TCP errors of joint commands")
    pr.add_argument("model", help="model.json written by identify fit")
    pr.add_argument("input", help="CSV (measurement or joints only) or URScript (.script)")
    pr.add_argument("--out", required=True, help="PRED.csv")
    pr.add_argument(
        "--threshold-mm", type=options.LENGTH_MM, default=None, help="flag errors above this"
    )
    pr.set_defaults(func=_predict)

    w = sub.add_parser("import-wam", help="convert the WAM laser-tracker files to CSV v1")
    w.add_argument("wam", help="grid.csv or random.csv of the WAM data set")
    w.add_argument("--out", required=True, help="CSV v1 file to write")
    w.add_argument(
        "--sign",
        default="auto",
        help="position = x_t + SIGN * dif; auto: the sign whose geometric fit has the lower chi2",
    )
    w.add_argument("--robot", default=None, help="robot file for --sign auto (WAM DH table)")
    w.set_defaults(func=_import_wam)

    compare.register(sub)


# --------------------------------------------------------------------------- fit


def _positive(name: str, v: float) -> None:
    if not v > 0:
        raise InputError(f"{name} must be > 0, got {v}")


def _carrying_target(robot: RobotModel, cell_spec: str) -> RobotModel:
    """``robot`` carrying the smart target of cell ``cell_spec``; the cell must name the same
    arm when ``robot`` is a built-in one."""
    cell = load_cell(cell_spec)
    base = robot.nominal.robot if robot.nominal is not None else robot.name
    if base in BUILTIN_ROBOTS and base != cell.robot.name:
        raise InputError(f"--cell {cell_spec}: its arm is the {cell.robot.name}, not the {base}")
    return cell.robot_with_target(robot)


@workers.owns_workers
@lock.holds_outputs("identify fit", lambda a: [a.out])
def _fit(args: argparse.Namespace) -> int:
    workers.keep_freed_memory()  # a batch command: reuse freed arrays (see there)
    for name in ("sigma_pos_mm", "sigma_rot_deg"):
        if getattr(args, name) is not None:
            _positive(f"--{name.replace('_', '-')}", getattr(args, name))
    if args.sigma_q_deg < 0:
        raise InputError(f"--sigma-q-deg must be >= 0, got {args.sigma_q_deg}")
    if not 0 <= args.max_order <= 40:
        raise InputError(f"--max-order must be in 0..40, got {args.max_order}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a directory")
    robot = formats.load_robot(args.robot, args.calibration)
    if args.cell is not None:
        robot = _carrying_target(robot, args.cell)
    outputs = ["model.json", "report.json", "residuals.csv"]
    if args.plots:
        outputs += FigureRenderer.names(robot.n_joints)
    refuse_overwriting_inputs(
        [("--out", out / n) for n in outputs],
        [
            args.meas,
            args.robot if Path(args.robot).is_file() else None,
            args.calibration,
            args.cell if args.cell and Path(args.cell).is_file() else None,
        ],
    )
    _, other = claim_fit_folder(out, Path(args.meas))
    forced = claim_output_folder(out, other, force=args.force)
    meas = formats.read_measurements(args.meas, robot.n_joints)
    formats.check_poses_for_fit(meas, robot, args.meas)
    spec = _fit_spec(args, meas)
    default = FitOptions().noise
    options = FitOptions(
        effects=() if args.effects is None else tuple(args.effects.split(",")),
        max_order=args.max_order,
        noise=InstrumentNoise(
            sigma_pos=default.sigma_pos if args.sigma_pos_mm is None else args.sigma_pos_mm * 1e-3,
            sigma_rot=default.sigma_rot
            if args.sigma_rot_deg is None
            else float(np.radians(args.sigma_rot_deg)),
            sigma_q=float(np.radians(args.sigma_q_deg)),
        ),
        margin=args.margin,
        auto_rescale=args.auto_rescale,
    )
    say = Progress(quiet=args.quiet)  # a bar on a terminal, stage lines in a log
    say(
        f"{meas.n_poses} poses, {'full pose' if meas.has_orientation else 'position only'}; "
        f"searching orders up to {args.max_order}"
    )
    try:
        res = fit_folder(
            meas,
            robot,
            out,
            options,
            source=args.meas,
            plots=args.plots,
            forced=forced,
            progress=say,
            spec=None if spec is None else spec.as_dict(),
        )
    finally:
        say.close()  # the bar is cleared before the summary
    if res.replacing:
        print(res.replacing, file=sys.stderr)
    for line in _fit_words(res.assessment, spec, out):
        print(line)
    print("statistics:")
    for line in res.assessment.summary():
        print(f"  {line}")
    print(f"wrote {out / 'model.json'}, {out / 'report.json'}, {out / 'residuals.csv'}")
    return 0


def _fit_words(a: Any, spec: Spec | None, out: Path) -> list[str]:
    """What the fit found, in the technician's words, before its statistics: how well the
    model explains the data, the TCP error the robot makes with its nominal kinematics
    against the spec, and what to do next."""
    from ...identify.select import chi2_check  # the fit's library (loaded by now)

    f, ws = a.fitted, a.workspace
    rot = (
        ""
        if f.residual_rot is None
        else f" and {float(np.sqrt(np.mean(np.sum(f.residual_rot**2, axis=1)))) * 1e3:.3f} mrad"
    )
    err = f"max {ws.max * 1e3:.3f} mm, mean {ws.mean * 1e3:.3f} mm"
    if spec is None:
        against = (
            "no accuracy spec set (identify fit --spec-mm, or spec_mm in the cell or robot file)"
        )
    else:
        v = {"mean": ws.mean, "std": ws.std, "max": ws.max}[spec.figure.value] * 1e3
        against = ("above " if v > spec.mm else "within ") + spec.words()
    return [
        f"the model explains the {f.n_poses} measured poses to {f.rms_pos * 1e3:.3f} mm RMS"
        f"{rot}; {chi2_check(f).message}",
        f"TCP error of the robot with its nominal kinematics, over the workspace: {err}; {against}",
        f"what next: quickhealth archive add {out} --robot NAME, then quickhealth report {out} "
        "(the verdict against the spec and the robot's baseline)",
    ]


def _fit_spec(args: argparse.Namespace, meas: Measurements) -> Spec | None:
    """The accuracy spec a fit records: --spec-mm, else the --cell's, the robot file's, or
    the one the run recorded from its cell (the measurement file's ``# spec_mm``)."""
    if args.spec_mm is not None:
        _positive("--spec-mm", args.spec_mm)
        return Spec(args.spec_mm, ThresholdFigure.MAX, "--spec-mm")
    if args.cell is not None:
        mm = load_cell(args.cell).spec_mm
        if mm is not None:
            return Spec(mm, ThresholdFigure.MAX, f"cell {args.cell}")
    mm = formats.robot_spec_mm(args.robot)
    if mm is not None:
        return Spec(mm, ThresholdFigure.MAX, f"robot file {Path(args.robot).name}")
    return spec_of_meta(meas.meta)


def csv_cells(values: Iterable[str]) -> list[str]:
    """Each text as one CSV cell, neutralised where a spreadsheet would run it as a formula
    (:func:`~..formats.common.csv_cell`) and quoted as the csv module quotes it (only when it
    holds a comma, a quote or a line break): for rows built by ``%`` formatting, where the
    other cells are numbers."""

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    out = []
    for v in values:
        s = formats.csv_cell(str(v))
        if "," in s or '"' in s or "\n" in s or "\r" in s:
            buf.seek(0)
            buf.truncate()
            w.writerow([s])
            s = buf.getvalue()[:-1]
        out.append(s)
    return out


# --------------------------------------------------------------------------- predict


def _predict(args: argparse.Namespace) -> int:
    if args.threshold_mm is not None:
        _positive("--threshold-mm", args.threshold_mm)
    refuse_overwriting_inputs([("--out", args.out)], [args.model, args.input])
    fm = formats.read_model(args.model)
    nj = fm.robot.n_joints
    inp = Path(args.input)
    meas = None
    if inp.suffix.lower() in (".script", ".urscript", ".urp"):
        q, src_lines = formats.read_urscript_joints(inp, nj)
        conditions: dict[str, F | None] = {}
        formats.check_joint_limits(q, fm.robot, str(inp), src_lines, what="target")
    else:
        meas = formats.read_measurements(inp, nj, joints_only=True)
        q, conditions = meas.q, meas.conditions()
        src_lines = None
        formats.check_joint_limits(q, fm.robot, str(inp))
    thr = None if args.threshold_mm is None else args.threshold_mm * 1e-3
    pred = _predict_chunked(fm, q, thr, conditions)
    cols = ["row"]
    if src_lines is not None:
        cols.append("line")
    if meas is not None and meas.pose_id is not None:
        cols.append("pose_id")
    cols += [f"q{i + 1}" for i in range(nj)] + ["x", "y", "z"]
    if fm.has_orientation:
        cols += ["pitch", "yaw", "roll"]
    cols += ["x_base", "y_base", "z_base"]
    cols += ["err_mm", "err_sigma_mm", "extrapolated"]
    has_meas = meas is not None and not np.all(np.isnan(meas.pos))
    band = None
    if has_meas:
        assert meas is not None
        cols += ["meas_minus_model_mm", "band95_mm"]
        band = _band_chunked(fm, meas)
    if thr is not None:
        cols += ["over_threshold"]
    qd = np.degrees(q)
    xyz = pred.T_instr_target[:, :3, 3] * 1e3
    rpy = np.degrees(R_to_rpy(pred.T_instr_target[:, :3, :3]))
    T_ib = fm.registration[0]  # the robot base (registered) in the instrument frame
    xyz_base = (pred.T_instr_target[:, :3, 3] - T_ib[:3, 3]) @ T_ib[:3, :3] * 1e3
    # one format string per row, numbers as columns (vectorised build; 200 000 rows in ~1 s)
    fmt = ["%d"]
    data: list[Any] = [np.arange(1, len(q) + 1)]
    if src_lines is not None:
        fmt.append("%d")
        data.append(np.asarray(src_lines))
    if meas is not None and meas.pose_id is not None:
        fmt.append("%s")
        data.append(np.asarray(csv_cells(meas.pose_id), dtype=object))
    fmt += ["%.6f"] * (nj + 3)
    data += list(qd.T) + list(xyz.T)
    if fm.has_orientation:
        fmt += ["%.7f"] * 3
        data += list(rpy.T)
    fmt += ["%.6f"] * 3
    data += list(xyz_base.T)
    fmt += ["%.6f", "%.6f", "%d"]
    data += [pred.err * 1e3, pred.err_sigma * 1e3, pred.extrapolated.astype(int)]
    if has_meas:
        assert meas is not None and band is not None
        fmt += ["%.6f", "%.6f"]
        data.append(np.linalg.norm(meas.pos * 1e3 - xyz, axis=1))
        data.append(band * 1e3)
    if thr is not None:
        fmt.append("%d")
        data.append(pred.over_threshold.astype(int))
    row_fmt = ",".join(fmt)
    cols_py = [c.tolist() for c in data]
    lines = [",".join(cols)] + [row_fmt % r for r in zip(*cols_py, strict=True)]
    formats.write_text_atomic(args.out, "\n".join(lines) + "\n")
    n_over = int(pred.over_threshold.sum())
    msg = (
        f"{len(q)} commands: predicted TCP error mean {pred.err.mean() * 1e3:.3f} mm, "
        f"max {pred.err.max() * 1e3:.3f} mm (row {int(np.argmax(pred.err)) + 1})"
    )
    if pred.extrapolated.any():
        msg += f"; {int(pred.extrapolated.sum())} outside the identified joint range"
    if has_meas:
        assert meas is not None
        d = np.linalg.norm(meas.pos * 1e3 - xyz, axis=1)
        msg += (
            f"; measured minus model: mean {d.mean():.3f} mm, rms {np.sqrt(np.mean(d**2)):.3f} mm"
        )
        assert band is not None
        msg += f", {np.mean(d <= band * 1e3):.1%} within band95"
    print(msg)
    print(
        "positions in the file: x_base, y_base, z_base in the robot base frame (mm); x, y, z"
        + (", pitch, yaw, roll" if fm.has_orientation else "")
        + " in the instrument frame the model was fitted in (mm, deg)"
    )
    if pred.assumed.describe():
        print(
            f"the input has no column for {', '.join(_missing(pred.assumed))}: predicted "
            f"{pred.assumed.describe()} (the model's reference conditions)"
        )
    print(f"wrote {args.out}")
    if thr is not None:
        print(f"{n_over} commands above {args.threshold_mm} mm")
        return 1 if n_over else 0
    return 0


PREDICT_CHUNK = 5000  # commands per block: memory stays bounded (~100 MB) for any file


def _band_chunked(fm: FittedModel, meas: Measurements) -> NDArray[np.float64]:
    """:func:`~quickhealth.identify.workspace.prediction_band` in blocks (bounded memory)."""
    n = meas.n_poses
    return np.concatenate(
        [
            prediction_band(fm, meas.subset(slice(a, a + PREDICT_CHUNK)))
            for a in range(0, n, PREDICT_CHUNK)
        ]
    )


def _predict_chunked(
    fm: FittedModel, q: F, thr: float | None, conditions: dict[str, F | None]
) -> CommandPrediction:
    """:func:`predict_commands` in blocks of ``PREDICT_CHUNK`` commands (bounded memory);
    ``conditions`` of every command by channel (``time``, ``temp`` …; None: not given)."""
    parts = []
    for a in range(0, len(q), PREDICT_CHUNK):
        b = a + PREDICT_CHUNK
        part = {c: None if v is None else v[a:b] for c, v in conditions.items()}
        parts.append(predict_commands(fm, q[a:b], thr, **part))
    if len(parts) == 1:
        return parts[0]
    return CommandPrediction(
        *(np.concatenate([getattr(p, f) for p in parts]) for f in (
            "T_instr_target", "err", "err_vec", "err_sigma", "over_threshold", "extrapolated"
        )),
        thr,
        parts[0].assumed,
    )  # fmt: skip


def _missing(c: Conditions) -> list[str]:
    return c.channels


# --------------------------------------------------------------------------- WAM import


def _import_wam(args: argparse.Namespace) -> int:
    robot_file = args.robot if args.robot and Path(args.robot).is_file() else None
    refuse_overwriting_inputs([("--out", args.out)], [args.wam, robot_file])
    if args.sign == "auto":
        if args.robot is None:
            raise InputError("--sign auto needs --robot (the WAM description file)")
        robot = formats.load_robot(args.robot)
        sign, chi = wam_sign(robot, args.wam)
        print(
            f"sign from the data: chi2 {chi[1.0]:.1f} (+1) vs {chi[-1.0]:.1f} (-1): using {sign:+.0f}"
        )
    else:
        try:
            sign = float(args.sign)
        except ValueError:
            raise InputError(f"--sign must be auto, +1 or -1, got {args.sign!r}") from None
        if sign not in (1.0, -1.0):
            raise InputError(f"--sign must be auto, +1 or -1, got {args.sign!r}")
    m = formats.read_wam_csv(args.wam, sign)
    m = dataclasses.replace(m, meta={**m.meta, "position": f"x_t + ({sign:+.0f}) * dif"})
    formats.write_measurements(args.out, m)
    print(f"wrote {args.out}: {m.n_poses} poses, position only")
    return 0
