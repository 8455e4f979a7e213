"""``quickhealth identify``: fit the error model to measurements, predict new commands.

quickhealth identify fit MEAS.csv --robot ROBOT [--calibration CAL.yaml] --out DIR
    [--effects LIST] [--max-order N]
    [--sigma-pos-mm S] [--sigma-rot-deg S] [--sigma-q-deg S] [--plots] [--auto-rescale]
quickhealth identify predict DIR/model.json INPUT --out PRED.csv [--threshold-mm T]
    INPUT: a measurement CSV, a CSV of joint columns only, or a URScript file (.script)
    whose movej/movel joint targets are predicted.  Exit 1 if --threshold-mm is given and
    some command's predicted error exceeds it.
quickhealth identify import-wam WAM.csv --out MEAS.csv [--sign auto|+1|-1] [--robot R]
    Converts the Barrett WAM laser-tracker files to CSV v1.
quickhealth identify compare DIR/model.json MEAS.csv --effects LIST [--heldout HELD.csv]
    [--folds K] [--json OUT.json] [--plots DIR]
    Held-out error without and with the effects (:mod:`quickhealth.station.compare`; the
    same command as the top-level ``quickhealth compare``).
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

from quickhealth.station import lock, options, workers

# the library's InstrumentNoise defaults (0.03 mm, 0.1 mrad): every door assesses alike
DEFAULT_SIGMA_POS_MM = 0.03
DEFAULT_SIGMA_ROT_DEG = math.degrees(1e-4)  # 0.1 mrad


def register(subparsers: Any) -> None:
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
    f.add_argument("--out", required=True, help="output directory")
    f.add_argument("--effects", default=None, help="comma-separated effect names")
    f.add_argument(
        "--max-order", type=options.ORDER, default=6, help="cap of every series' order (6)"
    )
    f.add_argument(
        "--sigma-pos-mm",
        type=options.SIGMA_POS_MM,
        default=DEFAULT_SIGMA_POS_MM,
        help=f"instrument position uncertainty per axis where the file has no sx..sz ({DEFAULT_SIGMA_POS_MM})",
    )
    f.add_argument(
        "--sigma-rot-deg",
        type=options.SIGMA_ROT_DEG,
        default=DEFAULT_SIGMA_ROT_DEG,
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

    from quickhealth.station import compare  # light: heavy imports are in its run()

    compare.register(sub)


# --------------------------------------------------------------------------- fit


def _positive(name: str, v: float) -> None:
    from quickhealth.identify.errors import InputError

    if not v > 0:
        raise InputError(f"{name} must be > 0, got {v}")


@workers.owns_workers
@lock.holds_outputs("identify fit", lambda a: [a.out])
def _fit(args: argparse.Namespace) -> int:
    import numpy as np

    from quickhealth.identify.assess import assess
    from quickhealth.identify.errors import InputError
    from quickhealth.identify.fit import InstrumentNoise
    from quickhealth.station import formats
    from quickhealth.station.report_json import write_report_json

    _positive("--sigma-pos-mm", args.sigma_pos_mm)
    _positive("--sigma-rot-deg", args.sigma_rot_deg)
    if args.sigma_q_deg < 0:
        raise InputError(f"--sigma-q-deg must be >= 0, got {args.sigma_q_deg}")
    if not 0 <= args.max_order <= 40:
        raise InputError(f"--max-order must be in 0..40, got {args.max_order}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a directory")
    from quickhealth.station.fsio import (
        claim_output_folder,
        make_dirs,
        refuse_overwriting_inputs,
        replacing_line,
        write_error,
    )

    robot = formats.load_robot(args.robot, args.calibration)
    outputs = ["model.json", "report.json", "residuals.csv"]
    if args.plots:
        outputs += ["workspace_histogram.png", "residuals.png"]
        outputs += [f"joint{j}_curves.png" for j in range(1, robot.n_joints + 1)]
    refuse_overwriting_inputs(
        [("--out", out / n) for n in outputs],
        [args.meas, args.robot if Path(args.robot).is_file() else None, args.calibration],
    )
    _, other = fit_folder_owner(out, Path(args.meas))
    forced = claim_output_folder(out, other, force=args.force)
    meas = formats.read_measurements(args.meas, robot.n_joints)
    formats.check_poses_for_fit(meas, robot, args.meas)
    noise = InstrumentNoise(
        sigma_pos=args.sigma_pos_mm * 1e-3,
        sigma_rot=float(np.radians(args.sigma_rot_deg)),
        sigma_q=float(np.radians(args.sigma_q_deg)),
    )
    from quickhealth.station.progress import Progress

    say = Progress(quiet=args.quiet)  # a bar on a terminal, stage lines in a log
    say(
        f"{meas.n_poses} poses, {'full pose' if meas.has_orientation else 'position only'}; searching orders up to {args.max_order}"
    )
    render = _FigureRenderer() if args.plots else None  # workers import matplotlib meanwhile
    try:
        a = assess(
            meas,
            robot,
            [] if args.effects is None else args.effects.split(","),
            noise=noise,
            max_order=args.max_order,
            margin=args.margin,
            auto_rescale=args.auto_rescale,
            progress=say,
        )
    except InputError as exc:
        say.close()
        if render is not None:
            render.close()
        if "too few" not in str(exc):
            raise InputError(f"{args.meas}: {exc}") from None
        n_lines = len(Path(args.meas).read_text(encoding="utf-8").splitlines())
        raise InputError(f"{args.meas}:{n_lines}:1: {exc}") from None
    say("writing the model, report and residuals")
    # write everything into a temporary directory first: nothing half-written on failure
    make_dirs(out.parent)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=".identify-", dir=out.parent))
    except OSError as exc:
        raise write_error(out, exc) from None
    try:
        if render is not None:
            render.run(a, tmp)
        formats.write_model(tmp / "model.json", a.fitted)
        write_report_json(tmp / "report.json", a, source=str(args.meas))
        formats.write_text_atomic(tmp / "residuals.csv", residual_table(a.fitted, meas))
        make_dirs(out)
        replaced = sorted(f.name for f in tmp.iterdir() if (out / f.name).exists())
        line = replacing_line(out, replaced, "the earlier fit of this data", forced)
        if line:
            print(line, file=sys.stderr)
        for f in tmp.iterdir():
            (tmp / f.name).replace(out / f.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        say.close()
    for line in a.summary():
        print(line)
    print(f"wrote {out / 'model.json'}, {out / 'report.json'}, {out / 'residuals.csv'}")
    return 0


def fit_folder_owner(out: Path, meas: Path) -> tuple[bool, list[str]]:
    """Whose is the output folder of ``identify fit MEAS --out DIR``?

    Returns whether ``DIR`` holds the input ``MEAS`` itself (the run folder of this data: its
    plan, journal, images and measurements are this run's), and what in ``DIR`` belongs to
    another kind or run (for :func:`~quickhealth.station.fsio.claim_output_folder`): outside
    the data's own folder a plan or a run's files, anywhere a fit whose report.json names
    another input file (or, outside the own folder, a fit that names none).
    """
    from quickhealth.identify.errors import InputError
    from quickhealth.station import formats
    from quickhealth.station.fsio import foreign_results, result_files

    if not out.is_dir():
        return False, []
    try:
        own = meas.is_file() and os.path.samefile(meas.parent, out)
    except OSError:
        own = False
    other = [] if own else foreign_results(out, "fit")
    fit = [n for n in result_files(out)["fit"] if n in ("model.json", "report.json")]
    if fit:
        src = None
        if (out / "report.json").is_file():
            try:
                doc = formats.read_report(out / "report.json")
                src = doc.get("input") if isinstance(doc.get("input"), str) else None
            except InputError:
                src = None
        if src is None:
            if not own:
                other.append(f"a fit of unknown data ({', '.join(fit)})")
        elif not _same_input(Path(src), meas, own):
            other.append(f"the fit of another measurement file, {src} ({', '.join(fit)})")
    return own, other


def _same_input(recorded: Path, meas: Path, own_folder: bool) -> bool:
    """Is the input a report.json records (as typed then) the file ``meas``?"""
    try:
        if recorded.is_file() and os.path.samefile(recorded, meas):
            return True
    except OSError:
        pass
    # typed from another working directory: in the data's own folder the name tells
    return own_folder and recorded.name == meas.name


def residual_table(fm: Any, meas: Any) -> str:
    """Per-pose measured-minus-model table (CSV: mm, deg; cells quoted by the csv module, so
    a pose_id holding a comma or a quote stays one cell)."""
    import csv
    import io

    import numpy as np

    cols = ["row", "pose_id"] + [f"q{i + 1}" for i in range(meas.n_joints)]
    cols += ["rx_mm", "ry_mm", "rz_mm", "r_mm"]
    if fm.residual_rot is not None:
        cols += ["rrx_deg", "rry_deg", "rrz_deg"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    qd = np.degrees(meas.q)
    for i in range(fm.n_poses):
        rp = fm.residual_pos[i] * 1e3
        v = [str(i + 1), "" if meas.pose_id is None else meas.pose_id[i]]
        v += [f"{x:.6f}" for x in qd[i]]
        v += [f"{x:.6f}" for x in rp] + [f"{np.linalg.norm(rp):.6f}"]
        if fm.residual_rot is not None:
            v += [f"{x:.7f}" for x in np.degrees(fm.residual_rot[i])]
        w.writerow(v)
    return buf.getvalue()


def csv_cells(values: Any) -> list[str]:
    """Each text as one CSV cell, quoted as the csv module quotes it (only when it holds a
    comma, a quote or a line break): for rows built by ``%`` formatting, where the other
    cells are numbers."""
    import csv
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    out = []
    for v in values:
        s = str(v)
        if "," in s or '"' in s or "\n" in s or "\r" in s:
            buf.seek(0)
            buf.truncate()
            w.writerow([s])
            s = buf.getvalue()[:-1]
        out.append(s)
    return out


def _render_figures(job: tuple[str, Any, Any, str]) -> str:
    """One PNG of ``identify fit --plots`` (runs in a worker process)."""
    from quickhealth.identify import report

    kind, data, extra, path = job
    if kind == "workspace":
        fig = report.workspace_histogram(data)
    elif kind == "residuals":
        fig = report.residual_plot(data, extra)
    else:
        fig = report.joint_curve_figure(data)
    from quickhealth.station.fsio import write_figure

    return write_figure(fig, path, dpi=100)


def _warm() -> None:
    import quickhealth.identify.report  # noqa: F401  (matplotlib, while the parent fits)


class _FigureRenderer:
    """The PNGs of ``--plots`` drawn by two worker processes: they import matplotlib while
    the fit runs, then draw one figure each at a time (8 figures, ~0.3 s each)."""

    def __init__(self) -> None:
        import multiprocessing

        ctx = multiprocessing.get_context("fork")
        self.pool = workers.Pool(max_workers=2, mp_context=ctx)
        self.warm = [self.pool.submit(_warm) for _ in range(2)]

    def run(self, a: Any, out: Path) -> None:
        jobs = [("workspace", a.workspace, None, str(out / "workspace_histogram.png"))]
        jobs += [("curves", c, None, str(out / f"joint{c.joint}_curves.png")) for c in a.curves]
        jobs.insert(1, ("residuals", a.fitted, a.measurements, str(out / "residuals.png")))
        try:
            list(self.pool.map(_render_figures, jobs))
        finally:
            self.close()

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


# --------------------------------------------------------------------------- predict


def _predict(args: argparse.Namespace) -> int:
    import numpy as np

    from quickhealth.identify.transforms import R_to_rpy
    from quickhealth.station import formats
    from quickhealth.station.fsio import refuse_overwriting_inputs

    if args.threshold_mm is not None:
        _positive("--threshold-mm", args.threshold_mm)
    refuse_overwriting_inputs([("--out", args.out)], [args.model, args.input])
    fm = formats.read_model(args.model)
    nj = fm.robot.n_joints
    inp = Path(args.input)
    meas = None
    if inp.suffix.lower() in (".script", ".urscript", ".urp"):
        q, src_lines = formats.read_urscript_joints(inp, nj)
        time = temp = None
        formats.check_joint_limits(q, fm.robot, str(inp), src_lines, what="target")
    else:
        meas = formats.read_measurements(inp, nj, joints_only=True)
        q, time, temp = meas.q, meas.time, meas.temp
        src_lines = None
        formats.check_joint_limits(q, fm.robot, str(inp))
    thr = None if args.threshold_mm is None else args.threshold_mm * 1e-3
    pred = _predict_chunked(fm, q, thr, time, temp)
    cols = ["row"]
    if src_lines is not None:
        cols.append("line")
    if meas is not None and meas.pose_id is not None:
        cols.append("pose_id")
    cols += [f"q{i + 1}" for i in range(nj)] + ["x", "y", "z"]
    if fm.has_orientation:
        cols += ["pitch", "yaw", "roll"]
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


def _band_chunked(fm: Any, meas: Any) -> Any:
    """:func:`~quickhealth.identify.workspace.prediction_band` in blocks (bounded memory)."""
    import numpy as np

    from quickhealth.identify.workspace import prediction_band

    n = meas.n_poses
    return np.concatenate(
        [
            prediction_band(fm, meas.subset(slice(a, a + PREDICT_CHUNK)))
            for a in range(0, n, PREDICT_CHUNK)
        ]
    )


def _predict_chunked(fm: Any, q: Any, thr: Any, time: Any, temp: Any) -> Any:
    """:func:`predict_commands` in blocks of ``PREDICT_CHUNK`` commands (bounded memory)."""
    import numpy as np

    from quickhealth.identify.workspace import CommandPrediction, predict_commands

    parts = []
    for a in range(0, len(q), PREDICT_CHUNK):
        b = a + PREDICT_CHUNK
        parts.append(
            predict_commands(
                fm,
                q[a:b],
                thr,
                time=None if time is None else time[a:b],
                temp=None if temp is None else temp[a:b],
            )
        )
    if len(parts) == 1:
        return parts[0]
    return CommandPrediction(
        *(np.concatenate([getattr(p, f) for p in parts]) for f in (
            "T_instr_target", "err", "err_vec", "err_sigma", "over_threshold", "extrapolated"
        )),
        thr,
        parts[0].assumed,
    )  # fmt: skip


def _missing(c: Any) -> list[str]:
    return [n for n, v in (("temp", c.temp_c), ("time", c.time_s)) if v is not None]


# --------------------------------------------------------------------------- WAM import


def wam_sign(robot: Any, path: str | Path) -> tuple[float, dict[float, float]]:
    """The sign of the ``dif`` columns: the one whose geometric-model fit has the lower χ²."""
    from quickhealth.identify.fit import InstrumentNoise, fit_model
    from quickhealth.identify.select import data_spec
    from quickhealth.station import formats

    chi = {}
    for s in (1.0, -1.0):
        m = formats.read_wam_csv(path, s)
        fm = fit_model(robot, m, data_spec(robot, m), noise=InstrumentNoise(sigma_pos=1e-3))
        chi[s] = fm.chi2_data
    return (1.0 if chi[1.0] <= chi[-1.0] else -1.0), chi


def _import_wam(args: argparse.Namespace) -> int:
    from quickhealth.identify.errors import InputError
    from quickhealth.station import formats
    from quickhealth.station.fsio import refuse_overwriting_inputs

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
    from dataclasses import replace

    m = replace(m, meta={**m.meta, "position": f"x_t + ({sign:+.0f}) * dif"})
    formats.write_measurements(args.out, m)
    print(f"wrote {args.out}: {m.n_poses} poses, position only")
    return 0
