"""quickhealth vision — the 7D camera: calibrate cameras, reprocess a run's stereo images.

    quickhealth vision calibrate --board SPEC --left GLOB [--right GLOB] --out CAL.json
    quickhealth vision measure RUN_DIR [--calibration CAL.json] [--target TARGET] [--jobs N] [--out CSV]

calibrate: one camera (--left only) or a stereo pair (paired by sorted file name).  SPEC is
chessboard:COLSxROWS:SQUARE_MM (inner corners) or charuco:SXxSY:SQUARE_MM:MARKER_MM:DICT.
Writes CAL.json and, beside it, CAL_residuals.png, CAL_coverage.png, CAL_uncertainty.png.
The verdict ("ok" / "unreliable" with reasons) is printed and stored; exit 0 either way
unless --fail-on-unreliable asks for exit 1.

measure: reads a `quickhealth run` folder (RUN_DIR/journal.jsonl names each captured pose's
joints, pan, time and image pair; rows give the target frame at pan 0, as the run does) or,
without a journal, RUN_DIR/images/index.csv (pose_id, q1..qN in deg, optional pan deg, time s,
temp °C) with the pairs RUN_DIR/images/<pose_id>_left.png / _right.png (rows give the plate
frame).  It measures the smart target's pose in every pair (in parallel) and writes
RUN_DIR/measurements.csv (CSV v1, one row per accepted pose, rejected poses listed as comments).  The calibration defaults to
RUN_DIR/calibration.json, else the reference design; the target to RUN_DIR/target.json, else
the reference target.  Nothing is written when the input is refused (exit status 2).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import InputError
from .. import options, workers
from ..formats.journal import Box
from ..formats.measurements import write_measurements
from ..fsio import refuse_overwriting_inputs, write_figure
from ..run import lock
from ..run.journal import JOURNAL, read_journal

F = NDArray[np.float64]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``vision calibrate`` and ``vision measure``."""
    p = subparsers.add_parser(
        "vision", help="7D camera: calibration and offline measurement", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    sub = p.add_subparsers(dest="vision_command", metavar="SUBCOMMAND", parser_class=type(p))
    c = sub.add_parser("calibrate", help="calibrate one camera or a stereo pair", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    c.add_argument(
        "--board",
        required=True,
        help="chessboard:COLSxROWS:SQUARE_MM or charuco:SXxSY:SQUARE_MM:MARKER_MM:DICT",
    )
    c.add_argument("--left", required=True, help="glob of the (left) camera's images (quote it)")
    c.add_argument("--right", help="glob of the right camera's images (stereo)")
    c.add_argument("--out", required=True, type=Path, help="CAL.json to write")
    c.add_argument(
        "--fail-on-unreliable", action="store_true", help="exit 1 when the verdict is 'unreliable'"
    )
    c.set_defaults(func=run_calibrate)
    m = sub.add_parser("measure", help="measure a run folder's stored stereo images", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    m.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    m.add_argument("--calibration", type=Path, help="stereo CAL.json")
    m.add_argument("--target", type=Path, help="target description file (JSON)")
    m.add_argument("--jobs", type=options.WORKERS, default=1, help="worker processes (default 1)")
    m.add_argument("--out", type=Path, help="CSV to write (default RUN_DIR/measurements.csv)")
    m.set_defaults(func=run_measure)
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])


def run_calibrate(args: argparse.Namespace) -> int:
    """Detect the board in every image, calibrate, write CAL.json and the report plots."""
    from ...vision.boards import parse_board_spec  # OpenCV and matplotlib from here on
    from ...vision.calibrate import Verdict, calibrate, detect_board
    from ...vision.plots import plot_coverage, plot_residuals, plot_uncertainty
    from ..formats import vision as io

    board = parse_board_spec(args.board)
    left = io.expand_glob(args.left, "--left")
    right = io.expand_glob(args.right, "--right") if args.right else None
    out: Path = args.out
    stem = out.with_suffix("")
    figs = ("residuals", "coverage", "uncertainty")
    refuse_overwriting_inputs(
        [("--out", out)] + [("--out", Path(f"{stem}_{n}.png")) for n in figs],
        [*left, *(right or [])],
    )
    if right is not None and len(right) != len(left):
        raise InputError(
            f"--left matches {len(left)} images but --right matches {len(right)}: a stereo set needs "
            "one right image per left image (paired by sorted file name)"
        )
    imgs_l = io.read_image_set(left)
    imgs_r = io.read_image_set(right) if right is not None else None
    if imgs_r is not None and imgs_r[0].shape != imgs_l[0].shape:
        raise InputError(
            f"{right[0]}: right images are {imgs_r[0].shape[1]}×{imgs_r[0].shape[0]}, left {imgs_l[0].shape[1]}×{imgs_l[0].shape[0]}"
        )  # type: ignore[index]
    size = (int(imgs_l[0].shape[1]), int(imgs_l[0].shape[0]))
    n = len(imgs_l) * (2 if imgs_r else 1)
    done = 0
    views_l, views_r = [], []
    for k, im in enumerate(imgs_l):
        views_l.append(detect_board(board, im))
        if imgs_r is not None:
            views_r.append(detect_board(board, imgs_r[k]))
        done += 2 if imgs_r is not None else 1
        sys.stderr.write(f"\rdetecting the board: {done}/{n} images")
    sys.stderr.write("\n")
    try:
        res = calibrate(board, views_l, size, views_r if imgs_r is not None else None)
    except ValueError as exc:
        raise InputError(
            f"--board {args.board}: {exc} (is the board spec right for these images?)"
        ) from None
    doc = io.calibration_to_json(res)
    doc["images"] = {
        "left": [str(p) for p in left],
        **({"right": [str(p) for p in right]} if right else {}),
    }
    doc["board"] = args.board
    io.write_json(out, doc)
    for name, plot in zip(figs, (plot_residuals, plot_coverage, plot_uncertainty), strict=True):
        write_figure(plot(res), f"{stem}_{name}.png", dpi=110)
    print("\n".join(res.summary()))
    print(f"wrote {out} and {stem.name}_{{residuals,coverage,uncertainty}}.png")
    return 1 if args.fail_on_unreliable and res.verdict is Verdict.UNRELIABLE else 0


def _read_journal(
    run: Path,
) -> tuple[list[str], F, F, F, F, list[tuple[Path, Path]], list[tuple[Box, Box] | None], list[int]]:
    """Captured poses of a `quickhealth run` folder (journal.jsonl), in execution order, with
    the pixel boxes each capture was first searched in (None where not recorded)."""
    from ..formats import vision as io  # OpenCV

    st = read_journal(run / JOURNAL)
    if not st.captured:
        raise InputError(f"{run / JOURNAL}: no captured poses")
    recs = [st.captured[i] for i in sorted(st.captured)]
    ids = [r.name for r in recs]
    try:
        q = np.array([r.q for r in recs], dtype=float)
    except ValueError as exc:
        raise InputError(
            f"{run / JOURNAL}: captured joint angles differ in number ({exc})"
        ) from None
    pan = np.array([r.pan for r in recs], dtype=float)
    time = np.array([r.time_s for r in recs], dtype=float)
    if any(len(r.images) != 2 for r in recs):
        raise InputError(f"{run / JOURNAL}: a captured record does not name two images")
    files = [(run / r.images[0], run / r.images[1]) for r in recs]
    for i, pid in enumerate(ids):
        io.check_pose_id(pid, f"{run / JOURNAL}: captured pose {i + 1}")
    if q.ndim != 2 or not np.all(np.isfinite(q)):
        raise InputError(f"{run / JOURNAL}: captured joint angles are not all finite numbers")
    bits = [int((r.camera or {}).get("bits", 8)) for r in recs]  # the depth they were taken at
    return ids, q, pan, time, np.full(len(ids), np.nan), files, [r.search for r in recs], bits


@workers.owns_workers
@lock.holds_outputs("vision measure", lambda a: [a.out or a.run_dir])
def run_measure(args: argparse.Namespace) -> int:
    """Measure every stored pair of a run folder and write its measurement CSV
    (:mod:`quickhealth.station.services.measuring`)."""
    from ..formats import vision as io  # OpenCV
    from ..services.measuring import StoredPair, measure_pairs, to_run_measurements

    run: Path = args.run_dir
    if not run.is_dir():
        raise InputError(f"{run}: not a run folder")
    if args.jobs < 1:
        raise InputError(f"--jobs {args.jobs}: need at least 1")
    cal = args.calibration or (run / "calibration.json")
    rig = (
        io.read_rig(cal)
        if cal.exists() or args.calibration
        else io.read_rig(io.data_path("reference_rig.json"))
    )
    tpath = args.target or (run / "target.json" if (run / "target.json").exists() else None)
    target = io.read_target(tpath)
    from_journal = (run / JOURNAL).is_file()
    if from_journal:
        ids, q, pan, time, temp, files, search, bits = _read_journal(run)
    else:
        ids, q, pan, time, temp = io.read_image_index(run / "images" / "index.csv")
        search, bits = [None] * len(ids), [8] * len(ids)
        files = [(run / "images" / f"{p}_left.png", run / "images" / f"{p}_right.png") for p in ids]
    if len(set(ids)) != len(ids):
        raise InputError(f"{run}: pose ids repeat; each pose needs its own id")
    reads = [cal if cal.exists() else None, tpath, run / JOURNAL, run / "images" / "index.csv"]
    refuse_overwriting_inputs(
        [("--out", args.out or run / "measurements.csv")],
        [p for p in reads if p is not None and Path(p).exists()] + [p for f in files for p in f],
    )
    pairs = [
        StoredPair(
            pid, files[k][0], files[k][1],
            None if np.isnan(pan[k]) else float(pan[k]),
            None if np.isnan(time[k]) else float(time[k]),
            search[k],
            bits[k] if bits[k] > 8 else None,
        )
        for k, pid in enumerate(ids)
    ]  # fmt: skip
    tty = sys.stderr.isatty()

    def progress(k: int, n: int) -> None:
        # on a terminal one line overwritten in place; in a log (a nightly job) a line at each
        # quarter, not 74 progress counts run together on one line
        if tty:
            sys.stderr.write(f"\rmeasuring: {k}/{n} pairs")
        elif n and (4 * k) // n > (4 * (k - 1)) // n:
            sys.stderr.write(f"measuring: {k}/{n} pairs\n")
        sys.stderr.flush()

    try:
        results = measure_pairs(rig, target, pairs, workers=args.jobs, progress=progress)
    finally:
        if tty:
            sys.stderr.write("\n")  # end the progress line (also before an error's one line)
    meta = {
        "instrument": "quickhealth 7D stereo camera",
        "calibration": str(cal if cal.exists() else "reference design"),
    }
    try:
        meas, rejected = to_run_measurements(
            ids,
            q,
            results,
            temp=None if np.all(np.isnan(temp)) else temp,
            at_pan0=from_journal,  # as `quickhealth run` records it: the target frame at pan 0
            meta=meta,
        )
    except InputError as exc:
        raise InputError(f"{run}: {exc}") from None
    out = args.out or (run / "measurements.csv")
    if out.exists():  # re-measuring stored images replaces the run's measurements: say so
        fitted = (out.parent / "model.json").exists()
        note = (
            f" ({out.parent / 'model.json'} was fitted to the old one: fit again)" if fitted else ""
        )
        print(f"replacing {out}{note}", file=sys.stderr)
    write_measurements(out, meas)
    print(f"measured {meas.n_poses}/{len(ids)} poses; rejected {len(rejected)}; wrote {out}")
    for r in rejected:
        print(f"  rejected {r}")
    return 0
