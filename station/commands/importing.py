"""``quickhealth import``: bring other instruments' files into CSV v1.

quickhealth import tracker FILE --out MEAS.csv [--preset ipa-ur10|wam]
    [--joints COLS] [--position X,Y,Z] [--deviation DX,DY,DZ [--deviation-sign +1|-1]]
    [--orientation A1,A2,A3 --euler SEQ] [--sigma-position SX,SY,SZ]
    [--sigma-orientation S1,S2,S3] [--temp COL] [--time COL] [--pose-id COL]
    [--sep auto|,|;|tab] [--decimal point|comma] [--no-header]
    [--length-unit mm|m|in] [--joint-unit deg|rad] [--angle-unit deg|rad] [--instrument TEXT]
    Reads a 3-DoF or 6-DoF laser-tracker export and writes a measurement file (CSV v1) with
    the orientation as a quaternion (qw, qx, qy, qz) and its one-angle uncertainty srot.
    A column is named by its header (with or without a unit suffix such as "[mm]") or by its
    1-based number.  Options override the preset's settings; --orientation none drops a
    preset's orientation.  docs/import.md.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import Any

import numpy as np

from ...identify.errors import InputError
from ..formats import write_measurements
from ..formats.tracker import PRESETS, TrackerLayout, layout_with, read_tracker
from ..fsio import refuse_overwriting_inputs


def register(subparsers: Any) -> None:
    """Add ``import tracker``."""
    p = subparsers.add_parser("import", help="convert other instruments' files to CSV v1")
    sub = p.add_subparsers(dest="import_command", metavar="SUBCOMMAND")
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])

    t = sub.add_parser(
        "tracker",
        help="a laser-tracker export (3-DoF or 6-DoF, any column layout) to CSV v1",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    t.add_argument("file", help="the tracker's export (delimited text)")
    t.add_argument(
        "--out", metavar="MEAS.csv", required=True, help="measurement file to write (CSV v1)"
    )
    t.add_argument("--preset", metavar="NAME", default=None, help="a known layout: ipa-ur10, wam")
    cols = t.add_argument_group("column mapping (header names or 1-based numbers, comma-separated)")
    cols.add_argument(
        "--joints", metavar="COLS", default=None, help="columns of q1 … qN, in joint order"
    )
    cols.add_argument("--position", metavar="X,Y,Z", default=None, help="columns of x, y, z")
    cols.add_argument(
        "--deviation",
        metavar="DX,DY,DZ",
        default=None,
        help="columns added to x, y, z (nominal + deviation files)",
    )
    cols.add_argument("--deviation-sign", metavar="±1", default=None, help="+1 or -1 (default +1)")
    cols.add_argument(
        "--orientation",
        metavar="A1,A2,A3",
        default=None,
        help="columns of the three Euler angles in --euler's axis order; 'none': position only",
    )
    cols.add_argument(
        "--euler",
        metavar="SEQ",
        default=None,
        help="the angles' convention as scipy names it: XYZ, ZYX, … intrinsic; xyz, zyx, … extrinsic",
    )
    cols.add_argument(
        "--sigma-position", metavar="SX,SY,SZ", default=None, help="columns of the x, y, z std devs"
    )
    cols.add_argument(
        "--sigma-orientation",
        metavar="S1,S2,S3",
        default=None,
        help="columns of the three angles' std devs",
    )
    cols.add_argument("--temp", metavar="COL", default=None, help="temperature column (°C)")
    cols.add_argument("--time", metavar="COL", default=None, help="time column (s)")
    cols.add_argument("--pose-id", metavar="COL", default=None, help="pose identifier column")
    cols.add_argument(
        "--joint-temps",
        metavar="T1,…,TN",
        default=None,
        help="columns of each joint's temperature (°C), joint order (default: temp_j1 … when "
        "the header has them)",
    )
    cols.add_argument(
        "--joint-torques",
        metavar="TAU1,…,TAUN",
        default=None,
        help="columns of each joint's measured torque (N·m), joint order (default: tau_j1 … "
        "when the header has them)",
    )
    fmt = t.add_argument_group("file format")
    fmt.add_argument("--sep", metavar="SEP", default=None, help="auto (default), ',', ';' or tab")
    fmt.add_argument("--decimal", metavar="MARK", default=None, help="point (default) or comma")
    fmt.add_argument("--no-header", action="store_true", help="no header row: columns by number")
    fmt.add_argument(
        "--length-unit", metavar="UNIT", default=None, help="mm, m or in (default: header, else mm)"
    )
    fmt.add_argument(
        "--joint-unit", metavar="UNIT", default=None, help="deg or rad (default: header, else deg)"
    )
    fmt.add_argument(
        "--angle-unit",
        metavar="UNIT",
        default=None,
        help="unit of the orientation angles and their std devs: deg or rad (default: header, else deg)",
    )
    fmt.add_argument("--instrument", metavar="TEXT", default=None, help="'# instrument:' metadata")
    t.set_defaults(func=_import_tracker)


def _columns(text: str | None) -> tuple[str, ...] | None:
    if text is None:
        return None
    return tuple(c.strip() for c in text.split(","))


def _import_tracker(args: argparse.Namespace) -> int:
    refuse_overwriting_inputs([("--out", args.out)], [args.file])
    if args.preset is not None and args.preset not in PRESETS:
        raise InputError(f"--preset {args.preset!r}: unknown; known: {', '.join(PRESETS)}")
    base = PRESETS[args.preset] if args.preset else TrackerLayout()
    sign = None
    if args.deviation_sign is not None:
        sign = {"+1": 1.0, "1": 1.0, "-1": -1.0}.get(args.deviation_sign.strip())
        if sign is None:
            raise InputError(f"--deviation-sign {args.deviation_sign!r}: must be +1 or -1")
    orientation = _columns(args.orientation)
    if orientation is not None and [c.lower() for c in orientation] == ["none"]:
        base = replace(base, orientation=None, euler=None, sigma_orientation=None)
        orientation = None
    layout = layout_with(
        base,
        joints=_columns(args.joints),
        position=_columns(args.position),
        deviation=_columns(args.deviation),
        deviation_sign=sign,
        orientation=orientation,
        euler=args.euler,
        sigma_position=_columns(args.sigma_position),
        sigma_orientation=_columns(args.sigma_orientation),
        temp=args.temp,
        time=args.time,
        pose_id=args.pose_id,
        joint_temps=_columns(args.joint_temps),
        joint_torques=_columns(args.joint_torques),
        separator=args.sep,
        decimal=args.decimal,
        length_unit=args.length_unit,
        joint_unit=args.joint_unit,
        angle_unit=args.angle_unit,
        header=False if args.no_header else None,
        instrument=args.instrument,
    )
    m = read_tracker(args.file, layout)
    write_measurements(args.out, m)
    what = "position only"
    if m.rot is not None:
        what = "position and orientation (quaternion)"
        if m.sigma_rot is not None:
            s = np.degrees(m.sigma_rot)
            what += f", srot {np.median(s):.2g} deg median ({s.min():.2g}-{s.max():.2g})"
    if m.joint_temp is not None:
        what += ", joint temperatures"
    if m.joint_torque is not None:
        what += ", joint torques"
    print(f"wrote {args.out}: {m.n_poses} poses, {m.n_joints} joints, {what}")
    return 0
