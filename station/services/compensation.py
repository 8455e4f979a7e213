"""A robot program compensated for the identified model, or refused with every reason (SI).

:func:`compensate` is ``quickhealth compensate`` without the files: joint targets in, the
compensated targets out, or :class:`CompensationRefused` naming each target that could make
the program worse.  Refused, per target: a target outside the robot's joint limits or outside
the joint range the model was identified on (the series would extrapolate), a compensation
that did not converge, a correction that reverses the direction the program moves a backlash
joint in, a correction above the cap on any joint, a compensated target outside the joint
limits.  Refused as a whole: a model with ``thermal`` / ``drift`` without the temperature /
the time the program runs at (unless the effect is left out).  With ``keep_refused`` a refused
target is kept as written instead (not compensated: a near-singular wrist, a correction
above the cap), the rest compensated, and :attr:`Compensated.kept` names each one.

SYNOPSIS::

    comp = compensate(read_model("fit/model.json"), q, tcp=np.zeros(3), temp_c=30.0)
    comp.q, comp.result.residual_pos
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from ...identify.compensate import Compensation, compensate_program
from ...identify.errors import InputError
from ...identify.fit import FittedModel

F = NDArray[np.float64]

#: The largest correction of any joint of any target accepted by default (rad): 1 degree.
MAX_CORRECTION = np.pi / 180.0


class Refusal(StrEnum):
    """Why one target of a program is refused."""

    OUTSIDE_LIMITS = "outside-limits"  # the target is outside the robot's joint limits
    OUTSIDE_MODEL = "outside-model"  # outside the joint range the model was identified on
    NOT_CONVERGED = "not-converged"  # the compensation did not converge (a singularity?)
    BACKLASH_REVERSED = "backlash-reversed"  # the correction reverses a backlash joint's move
    TOO_LARGE = "too-large"  # a correction above the cap
    COMPENSATED_OUTSIDE = "compensated-outside"  # the compensated target leaves the limits


@dataclass(frozen=True)
class Refused:
    """One refused target: which (0-based), why, and the joint (0-based) with its angle
    and the limits it broke (rad; ``value`` is the correction for :attr:`Refusal.TOO_LARGE`)."""

    target: int
    why: Refusal
    joint: int | None = None
    value: float = float("nan")
    lo: float = float("nan")
    hi: float = float("nan")


class CompensationRefused(InputError):
    """The program cannot be compensated safely: ``refused`` names each target and why."""

    def __init__(self, refused: Sequence[Refused], message: str | Sequence[str]) -> None:
        lines = [message] if isinstance(message, str) else list(message)
        super().__init__("\n".join(lines))
        self.refused = tuple(refused)
        # one line each on the command line, however a file name in them breaks
        self.findings = lines


@dataclass(frozen=True)
class Compensated:
    """A compensated program: its new targets (rad, program order), the change of every
    joint (rad) and the library's result (errors before and after, what was compensated)."""

    q: F
    dq: F
    result: Compensation
    kept: tuple[Refused, ...] = ()  # targets kept as written (``keep_refused``), and why


def needed_conditions(fm: FittedModel, leave_out: Sequence[str] = ()) -> dict[str, list[str]]:
    """The effects of the model (not left out) that need the temperature (``"temp"``), the
    time (``"time"``) or the joints' temperature (``"joint_temp"``) the program runs at."""
    return {
        col: [e.name for e in fm.effects if col in e.requires() and e.name not in leave_out]
        for col in ("temp", "time", "joint_temp")
    }


def refused_targets(fm: FittedModel, q: F) -> list[Refused]:
    """The targets outside the robot's joint limits or outside the range the model was
    identified on (checked before compensating)."""
    lo, hi = fm.robot.q_min, fm.robot.q_max
    out = []
    for k in range(len(q)):
        for j in range(q.shape[1]):
            v = q[k, j]
            if not lo[j] <= v <= hi[j]:
                out.append(Refused(k, Refusal.OUTSIDE_LIMITS, j, v, lo[j], hi[j]))
            elif not fm.spec.q_lo[j] - 1e-9 <= v <= fm.spec.q_hi[j] + 1e-9:
                out.append(
                    Refused(k, Refusal.OUTSIDE_MODEL, j, v, fm.spec.q_lo[j], fm.spec.q_hi[j])
                )
    return out


def compensate(
    fm: FittedModel,
    q: F,
    *,
    T_flange_tcp: F | None = None,
    temp_c: float | None = None,
    time_s: float | None = None,
    joint_temp_c: float | Sequence[float] | None = None,
    leave_out: Sequence[str] = (),
    max_correction: float = MAX_CORRECTION,
    describe: Callable[[Sequence[Refused]], str | list[str]] | None = None,
    keep_refused: bool = False,
) -> Compensated:
    """Compensate joint targets ``q`` (n, nj), rad, with model ``fm``.

    Parameters
    ----------
    T_flange_tcp : ndarray (4, 4), optional
        The tool centre point on the flange (default the flange).
    temp_c, time_s : float, optional
        The temperature (°C) and the time (s, the fitted run's clock) the program runs at:
        needed when the model has ``thermal`` / ``drift`` (not left out).
    joint_temp_c : float or sequence of float, optional
        The joints' temperature (°C, all or one per joint): needed by ``thermal:jK``.
    leave_out : sequence of str
        Effects of the model not to compensate.
    max_correction : float, rad
        The largest accepted change of any joint of any target.
    describe : callable, optional
        Words for the refused targets (the door's, with its units); default a count.
    keep_refused : bool
        Keep each refused target as written (uncompensated) instead of refusing the
        program: the way past a near-singular target; :attr:`Compensated.kept` says which.

    Raises
    ------
    InputError
        A condition the model needs is missing.
    CompensationRefused
        Some target is refused (nothing should be written).
    """
    words = describe or (lambda r: f"{len(r)} targets refused")
    bad = refused_targets(fm, q)
    if bad and not keep_refused:
        raise CompensationRefused(bad, words(bad))
    comp = compensate_program(
        fm,
        q,
        T_flange_tcp,
        temp_c=temp_c,
        time_s=time_s,
        joint_temp_c=joint_temp_c,
        leave_out=leave_out,
    )
    dq = comp.q - q
    lo, hi = fm.robot.q_min, fm.robot.q_max
    settled = comp.approach_settled if comp.approach_settled is not None else np.ones(len(q), bool)
    for k in range(len(q)):
        if not np.all(np.isfinite(comp.q[k])) or not comp.converged[k]:
            bad.append(Refused(k, Refusal.NOT_CONVERGED))
            continue
        if not settled[k]:
            bad.append(Refused(k, Refusal.BACKLASH_REVERSED))
        j = int(np.argmax(np.abs(dq[k])))
        if abs(dq[k, j]) > max_correction:
            bad.append(Refused(k, Refusal.TOO_LARGE, j, dq[k, j], -max_correction, max_correction))
        out_of = np.flatnonzero((comp.q[k] < lo) | (comp.q[k] > hi))
        if out_of.size:
            j = int(out_of[0])
            bad.append(Refused(k, Refusal.COMPENSATED_OUTSIDE, j, comp.q[k, j], lo[j], hi[j]))
    if bad and not keep_refused:
        raise CompensationRefused(bad, words(bad))
    kept = sorted({r.target for r in bad})
    new_q = comp.q.copy()
    new_q[kept] = q[kept]  # as written: never worse than the program was
    return Compensated(new_q, new_q - q, comp, tuple(sorted(bad, key=lambda r: r.target)))
