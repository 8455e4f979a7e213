"""``quickhealth compensate``: rewrite a program's joint targets so the modelled TCP hits them.

quickhealth compensate MODEL.json PROGRAM --out NEW_PROGRAM [--errors ERR.csv] [--tcp-mm X,Y,Z]
    [--temp-c C] [--time-s S] [--leave-out EFFECTS] [--max-correction-deg D] [--keep-refused]
    PROGRAM: URScript (.script) or a CSV of joint columns q1..qN (deg).  The compensation and
    every refusal are :func:`quickhealth.station.services.compensation.compensate`'s; this
    command reads and writes the files and says, one line per target, what was refused
    (exit 2, nothing written).  With --keep-refused such targets (a near-singular wrist, a
    correction above the cap) are kept as written, uncompensated, one line each says so,
    and the rest is compensated.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...identify.errors import InputError
from ...identify.fit import FittedModel
from ...identify.urscript import MOTIONS, replace_targets
from .. import formats
from ..formats import excerpt
from ..fsio import refuse_overwriting_inputs

if TYPE_CHECKING:  # types only: the compensation loads scipy.optimize, --help must not wait
    from ...identify.compensate import Compensation
    from ..services.compensation import Refused


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add ``compensate``."""
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
        "--keep-refused",
        action="store_true",
        help="keep a target that would be refused (near a singularity, a correction above the "
        "cap, outside the model's range) as written, uncompensated, and compensate the rest; "
        "each is listed",
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
        "--joint-temp-c",
        default=None,
        help="the joints' temperature the program runs at, degC: one value or one per joint "
        "(needed by 'thermal:jK')",
    )
    c.add_argument(
        "--leave-out",
        default=None,
        help="comma-separated effects of the model not to compensate (e.g. drift)",
    )
    c.add_argument(
        "--leave",
        metavar="MOVE",
        action="append",
        default=[],
        help="motion commands to keep as written where their target cannot be compensated "
        "(a p[...] pose, a variable, speedl, force_mode ...; comma-separated or repeated): "
        "listed in the summary; without it such a program is refused",
    )
    c.set_defaults(func=_compensate)


def _compensate(args: argparse.Namespace) -> int:
    """Compensate a program; refuse (exit 2, nothing written) anything that could make it worse."""
    from ..services.compensation import compensate, needed_conditions  # scipy.optimize

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
    needs = needed_conditions(fm, leave_out)
    if needs["temp"] and args.temp_c is None:
        raise InputError(
            f"{args.model}: the model has {needs['temp'][0]!r}: give the temperature the "
            "program runs at with --temp-c (its link lengths refer to 20 degC), or leave it "
            f"out with --leave-out {needs['temp'][0]}; nothing written"
        )
    joint_temp = _joint_temps(args.joint_temp_c, nj)
    if needs["joint_temp"] and joint_temp is None:
        raise InputError(
            f"{args.model}: the model has {needs['joint_temp'][0]!r}: give the joints' "
            "temperature the program runs at with --joint-temp-c (one value or one per joint, "
            f"degC), or leave it out with --leave-out {needs['joint_temp'][0]}; nothing written"
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
    leave = [m.strip() for x in args.leave for m in x.split(",") if m.strip()]
    unknown = [m for m in leave if m not in MOTIONS]
    if unknown:
        raise InputError(
            f"--leave {excerpt(unknown[0])}: not a URScript motion command ({', '.join(MOTIONS)})"
        )
    prog = Path(args.program)
    is_script = prog.suffix.lower() in (".script", ".urscript", ".urp")
    if leave and not is_script:
        raise InputError("--leave is for URScript programs; a CSV of joints has no commands")
    if is_script:
        text, targets = formats.read_urscript(prog, nj, leave)
        q = targets.q
        where = [f"{prog}:{ln}: target {k + 1}" for k, ln in enumerate(targets.lines)]
    else:
        q = formats.read_measurements(prog, nj, joints_only=True).q
        where = [f"{prog}: target {k + 1}" for k in range(len(q))]
    c = compensate(
        fm,
        q,
        T_flange_tcp=T_tcp,
        temp_c=args.temp_c,
        time_s=args.time_s,
        joint_temp_c=joint_temp,
        leave_out=leave_out,
        max_correction=np.radians(cap),
        describe=lambda refused: _refusals(refused, where, cap),
        keep_refused=args.keep_refused,
    )
    comp = c.result
    dq = np.degrees(c.dq)
    kept = sorted({r.target for r in c.kept})
    done = np.setdiff1d(np.arange(len(q)), kept)
    if is_script:
        new_text = replace_targets(text, targets.spans, c.q)
    else:
        lines = [",".join(f"q{j + 1}" for j in range(nj))]
        lines += [",".join(f"{v:.9f}" for v in np.degrees(row)) for row in c.q]
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
    before, after = comp.error_before_pos * 1e3, comp.residual_pos * 1e3
    after = np.where(np.isin(np.arange(len(q)), kept), before, after)  # kept: as before
    head = f"{len(q)} targets" if not kept else f"{len(done)} of {len(q)} targets compensated"
    print(
        f"{head}: predicted TCP error {before.mean():.4f} mm mean ({before.max():.4f} mm max) "
        f"before, {after.mean():.4f} mm mean ({after.max():.4f} mm max) after; largest "
        f"correction {np.abs(dq).max():.4f} deg (cap {cap:g} deg)"
    )
    for line in _refusals(c.kept, where, cap, kept=True):
        print(line)
    for line in _compensation_notes(fm, comp, args):
        print(line)
    if is_script and targets.left:
        print(_left_as_written(targets.left))
    print(f"wrote {args.out}" + (f", {args.errors}" if args.errors else ""))
    return 0


def _left_as_written(left: Sequence[tuple[int, int, str, str]]) -> str:
    """The summary line of the motions ``--leave`` kept as written (never silently)."""
    by: dict[str, list[str]] = {}
    for line, _, cmd, _ in left:
        by.setdefault(cmd, []).append(str(line))
    what = "; ".join(
        f"{cmd} at line{'s' if len(ls) > 1 else ''} {', '.join(ls[:8])}"
        + (" …" if len(ls) > 8 else "")
        for cmd, ls in by.items()
    )
    return (
        f"left as written (--leave): {len(left)} motion(s), not compensated: {what}; where "
        "the arm is after them is not modelled, and the next target's approach is taken from "
        "the target before them"
    )


def _joint_temps(text: str | None, n_joints: int) -> list[float] | None:
    """``--joint-temp-c``: one temperature for every joint or one per joint (degC)."""
    if text is None:
        return None
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputError(f"--joint-temp-c must be degC numbers, got {text!r}") from None
    if len(vals) not in (1, n_joints) or not all(-40.0 <= v <= 150.0 for v in vals):
        raise InputError(
            f"--joint-temp-c must be one temperature or {n_joints} (one per joint), each in "
            f"[-40, 150] degC, got {text!r}"
        )
    return vals * n_joints if len(vals) == 1 else vals


def _refusals(
    refused: Sequence[Refused], where: Sequence[str], cap: float, *, kept: bool = False
) -> list[str]:
    """One line per refused target (deg), each ending "nothing written" (``kept``: "kept as
    written, not compensated")."""
    from ..services.compensation import Refusal  # scipy.optimize (loaded by now)

    lines = []
    for r in refused:
        at, j = where[r.target], None if r.joint is None else r.joint + 1
        v, lo, hi = np.degrees([r.value, r.lo, r.hi])
        if r.why is Refusal.OUTSIDE_LIMITS:
            x = f"joint {j} at {v:.6g} deg is outside the robot's limits [{lo:.6g}, {hi:.6g}] deg"
        elif r.why is Refusal.OUTSIDE_MODEL:
            x = (
                f"joint {j} at {v:.6g} deg is outside the range the model was identified on "
                f"[{lo:.6g}, {hi:.6g}] deg: the model would extrapolate"
            )
        elif r.why is Refusal.NOT_CONVERGED:
            x = "compensation did not converge (near a singularity?)"
        elif r.why is Refusal.BACKLASH_REVERSED:
            x = (
                "the correction reverses the direction the program moves a backlash joint "
                "into this target (the move is smaller than the correction): the side the "
                "gear rests on is undefined"
            )
        elif r.why is Refusal.TOO_LARGE:
            x = f"joint {j} correction {v:+.4g} deg exceeds --max-correction-deg {cap:g}"
        else:
            x = f"compensated joint {j} at {v:.6g} deg is outside the robot's limits"
        lines.append(
            f"{at}: {x}; " + ("kept as written, not compensated" if kept else "nothing written")
        )
    if lines and not kept:  # the way past it, said where the refusal is
        lines[-1] += " (--keep-refused keeps such targets as written and compensates the rest)"
    return lines


def _compensation_notes(fm: FittedModel, comp: Compensation, args: argparse.Namespace) -> list[str]:
    """The lines that say what the compensation used and what it left out (never silently)."""
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
    # what each compensated effect warns about the program (a move smaller than a backlash's
    # play leaves a real gear between its two sides)
    for e, p in zip(fm.effects, fm.effect_params, strict=True):
        if e.name in comp.effects:
            out += e.correction_notes(np.asarray(p, float), comp.q)
    return out
