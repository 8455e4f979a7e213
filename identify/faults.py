"""The fault dictionary: the single physical faults a robot has, and changes named by them.

A robot changes by *physical faults*: a joint's encoder zero moves after a collision or a
motor swap, an axis tilts when a bearing is damaged, a link bends, a gearbox wears.  The error
model (METHOD.md Eq. 1–4) describes each of them as a small change of its error motions, but
the fit sees them through a fixed gauge (docs/identify.md): coefficients that base and tool
can take up are held at zero, so a zero offset of joint 2 appears as a tilt of joint 1 about
y plus a radial motion of joint 1.  Naming a change coordinate by coordinate therefore names
the gauge, not the robot.  This module defines the faults in the robot's own terms and maps
each through any fitted model's gauge, so that every door (trend, check, report, TUI) names a
change by the fault that explains it, in the fault's own unit.

The faults of joint ``i`` (frames as in :mod:`.robot`: ``E_i`` sits right after ``Rz(θ_i)``,
before the link transform ``C_i``; ``E_0`` is the base, ``E_{n+1}`` the tool):

======================  ==============================================  ======================
key                     physical fault                                  in the error model
======================  ==============================================  ======================
``jI.zero``             encoder zero offset: true angle − reading       ``E_i`` εz = s
``jI.scale``            joint scale (gear ratio): ``Δθ = s · θ``        ``E_i`` εz = s · θ_i
``jI.tilt_x``           joint i's axis tilted about x of the frame      a rotation after
``jI.tilt_y``           before it (``C_{i-1}``'s end), at its origin    ``C_{i-1}``: ``E_{i-1}``
                                                                        through ``Ad(C_{i-1})``
``jI.length``           link i's length (``a_i``: across joint i's      ``E_i`` δ along the
                        axis)                                           link's x-y direction
``jI.offset``           link i's offset (``d_i``: along joint i's axis) ``E_i`` δz = s
``backlash:jI`` …       an effect (backlash, compliance, cyclic error)  the effect's parameter
======================  ==============================================  ======================

A tilt of joint 1's axis, a change of ``d_1`` and every constant of the last joint are the
robot's mounting and the target's: the set-up (base and tool) takes them up, so
self-referenced data cannot see them; :func:`fault_images` finds such faults numerically
(their effect on the measured poses lies in the set-up's span) and they are never tested.
Some faults move the TCP exactly alike: on a UR, a tilt of joint 5 about its frame's y is
joint 4's zero offset (the axes meet).  Geometry cannot tell them apart; the change is named
by the one the prior (:data:`PRIOR`) finds more likely, the other listed as an alternative.

The prior: how often each kind of fault occurs, as relative weights (engineering judgement,
no published statistics exist; :data:`PRIOR`): a zero offset (collision, motor or encoder
swap, a lost zero reference) is by far the most common degradation of an arm; backlash from
gear wear next; a changed compliance (payload, gear stiffness); then the rare ones: a wrong
gear-ratio setting, a damaged bearing tilting an axis, a bent link, a cyclic gear error.

SYNOPSIS::

    faults = fault_dictionary(robot)
    img = fault_images(fitted, faults, q_eval)          # each fault in the fit's gauge
    named = name_changes(d, S, img.of(labels), img.faults, alpha=1e-4)
    named[0].line()   # "joint 2 zero offset changed by -0.300 ± 0.010 mrad (z = -30.0, p = …)"
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from .errormodel import MOTIONS, ErrorModelSpec

F = NDArray[np.float64]


class FaultKind(StrEnum):
    """The kinds of single physical faults."""

    ZERO = "zero"
    SCALE = "scale"
    TILT_X = "tilt_x"
    TILT_Y = "tilt_y"
    LENGTH = "length"
    OFFSET = "offset"
    BACKLASH = "backlash"
    COMPLIANCE = "compliance"
    CYCLIC = "cyclic"
    OTHER = "other"  # an effect kind the dictionary has no words for (a registered effect)
    SETUP = "setup"  # the target moved on the flange: no fault of the robot


#: Relative prior weight of each kind of fault (how often it occurs; see the module doc).
PRIOR: dict[FaultKind, float] = {
    FaultKind.ZERO: 10.0,
    FaultKind.BACKLASH: 4.0,
    FaultKind.COMPLIANCE: 2.0,
    FaultKind.SCALE: 1.0,
    FaultKind.TILT_X: 1.0,
    FaultKind.TILT_Y: 1.0,
    FaultKind.LENGTH: 1.0,
    FaultKind.OFFSET: 1.0,
    FaultKind.CYCLIC: 1.0,
    FaultKind.OTHER: 1.0,
    FaultKind.SETUP: 2.0,
}

#: Words, likely cause and what to do, per kind (``{i}``: the joint).
_WORDS: dict[FaultKind, tuple[str, str, str]] = {
    FaultKind.ZERO: (
        "joint {i} zero offset",
        "encoder or zero reference (a collision, a motor or encoder swap)",
        "re-zero joint {i} or recalibrate",
    ),
    FaultKind.SCALE: (
        "joint {i} scale (gear ratio)",
        "gear ratio or encoder resolution setting",
        "check joint {i}'s gear ratio and encoder settings, then recalibrate",
    ),
    FaultKind.TILT_X: (
        "joint {i} tilt about x",
        "joint {i}'s bearing or mounting (collision damage, a loose joint)",
        "inspect joint {i}'s bearing and mounting, then recalibrate",
    ),
    FaultKind.TILT_Y: (
        "joint {i} tilt about y",
        "joint {i}'s bearing or mounting (collision damage, a loose joint)",
        "inspect joint {i}'s bearing and mounting, then recalibrate",
    ),
    FaultKind.LENGTH: (
        "link {i} length",
        "link {i} bent or deformed, or grown with temperature",
        "inspect link {i} for damage, check the temperature, then recalibrate",
    ),
    FaultKind.OFFSET: (
        "link {i} offset",
        "link {i} bent or deformed, or grown with temperature",
        "inspect link {i} for damage, check the temperature, then recalibrate",
    ),
    FaultKind.BACKLASH: (
        "joint {i} backlash",
        "wear or play in joint {i}'s gearbox",
        "inspect joint {i}'s gearbox for wear",
    ),
    FaultKind.COMPLIANCE: (
        "joint {i} compliance",
        "joint {i}'s gearbox stiffness, or the payload changed",
        "check the payload setting, inspect joint {i}'s gearbox",
    ),
    FaultKind.CYCLIC: (
        "joint {i} cyclic error",
        "joint {i}'s gear (harmonic drive) or encoder eccentricity",
        "inspect joint {i}'s gearbox",
    ),
    FaultKind.OTHER: (
        "joint {i} {effect}",
        "a physical effect of joint {i}",
        "run a full assessment and diagnose",
    ),
    FaultKind.SETUP: (
        "target moved on the flange",
        "the target was re-mounted or knocked: no change of the robot",
        "check the target's mounting; measure a new baseline if it was re-mounted",
    ),
}

#: Display unit and factor from the SI unit of a fault's size.
DISPLAY: dict[str, tuple[str, float]] = {
    "rad": ("mrad", 1e3),
    "m": ("mm", 1e3),
    "1": ("ppm", 1e6),
}

#: A link length or offset below this (m) is no link feature of its own (a DH zero).
MIN_LINK = 1e-3


@dataclass(frozen=True)
class FaultTerm:
    """One part of a fault in the error model: ``coef × profile`` on motion ``motion`` of
    frame ``frame`` (0 base, 1 … nj joints, nj + 1 tool).  ``profile`` ``"const"`` is 1,
    ``"angle"`` the frame's own joint reading (rad)."""

    frame: int
    motion: int  # index into MOTIONS
    coef: float
    profile: str = "const"


@dataclass(frozen=True)
class Fault:
    """One single physical fault (see the module doc).

    ``terms``: the fault's unit size in the error model (geometric faults); ``coordinates``:
    the model parameters the fault *is* (an effect's parameters, a tool coordinate of a
    set-up fault), ``effect`` the effect's name.  ``unit`` is the SI unit of its size
    (``rad``, ``m``, ``1`` for a ratio, or an effect's parameter unit).
    """

    key: str
    kind: FaultKind
    joint: int  # 1-based
    unit: str
    words: str
    cause: str
    action: str
    prior: float
    terms: tuple[FaultTerm, ...] = ()
    effect: str | None = None
    coordinates: tuple[str, ...] = ()

    @property
    def n_params(self) -> int:
        """Dimension of the fault (1, or an effect's parameter count)."""
        return max(len(self.coordinates), 1)

    @property
    def robot_fault(self) -> bool:
        """False for a set-up change (the target on the flange)."""
        return self.kind is not FaultKind.SETUP

    @property
    def display(self) -> tuple[str, float]:
        """Display unit and factor from SI (``("mrad", 1e3)``)."""
        return DISPLAY.get(self.unit, (self.unit, 1.0))

    def raw_vector(self, spec: ErrorModelSpec) -> F:
        """The fault's unit size as Chebyshev coefficients of ``spec`` (injecting it into a
        twin's truth, e.g.); a linear profile needs order ≥ 1 of its motion.

        Raises
        ------
        ValueError
            An effect fault, or a motion of too low an order in ``spec``.
        """
        if not self.terms:
            raise ValueError(f"{self.key} is a model parameter, not a set of error motions")
        idx = spec.index()
        out = np.zeros(spec.n_params)
        for t in self.terms:
            rows = np.flatnonzero((idx[:, 0] == t.frame) & (idx[:, 1] == t.motion))
            need = 1 if t.profile == "angle" else 0
            if rows.size < need + 1:
                raise ValueError(
                    f"{self.key} needs order {need} of {spec.frame_name(t.frame)}."
                    f"{MOTIONS[t.motion]}"
                )
            if t.profile == "const":
                out[rows[0]] += t.coef
            else:  # θ = mid + half · u over the spec's range
                lo, hi = spec.q_lo[t.frame - 1], spec.q_hi[t.frame - 1]
                out[rows[0]] += t.coef * 0.5 * (lo + hi)
                out[rows[1]] += t.coef * 0.5 * (hi - lo)
        return out


def _fault(kind: FaultKind, joint: int, unit: str, terms: Sequence[FaultTerm] = (), *,
           effect: str | None = None, coordinates: Sequence[str] = (), key: str | None = None,
           words: str | None = None) -> Fault:  # fmt: skip
    w, cause, action = _WORDS[kind]
    fmt = {"i": joint, "effect": effect or ""}
    return Fault(
        key=key or f"j{joint}.{kind.value}",
        kind=kind,
        joint=joint,
        unit=unit,
        words=words or w.format(**fmt),
        cause=cause.format(**fmt),
        action=action.format(**fmt),
        prior=PRIOR[kind],
        terms=tuple(terms),
        effect=effect,
        coordinates=tuple(coordinates),
    )


def _rotation_at(C: F, axis: int, frame: int) -> list[FaultTerm]:
    """A unit rotation about ``axis`` (0 x, 1 y) of the frame at the end of ``C``, at its
    origin, as a twist of the frame before ``C`` (the adjoint): ``ω' = R_C a``,
    ``v' = p_C × ω'``."""
    a = np.zeros(3)
    a[axis] = 1.0
    w = C[:3, :3] @ a
    v = np.cross(C[:3, 3], w)
    tw = np.concatenate([v, w])
    return [FaultTerm(frame, m, float(c)) for m, c in enumerate(tw) if abs(c) > 1e-12]


def geometric_faults(robot) -> tuple[Fault, ...]:  # type: ignore[no-untyped-def]
    """Zero offset, scale, both tilts, link length and offset of every joint of ``robot``
    (a :class:`~.robot.RobotModel`); which of them the data can see is decided per model
    (:func:`fault_images`)."""
    out: list[Fault] = []
    nj = robot.n_joints
    for i in range(1, nj + 1):
        out.append(_fault(FaultKind.ZERO, i, "rad", [FaultTerm(i, 5, 1.0)]))
        out.append(_fault(FaultKind.SCALE, i, "1", [FaultTerm(i, 5, 1.0, "angle")]))
        if i >= 2:  # joint 1's axis is the base's: a set-up change
            C = np.asarray(robot.links[i - 1], float)
            for axis, kind in ((0, FaultKind.TILT_X), (1, FaultKind.TILT_Y)):
                out.append(_fault(kind, i, "rad", _rotation_at(C, axis, i - 1)))
        p = np.asarray(robot.links[i], float)[:3, 3]
        radial = float(np.hypot(p[0], p[1]))
        if radial > MIN_LINK:
            ux, uy = p[0] / radial, p[1] / radial
            terms = [FaultTerm(i, m, c) for m, c in ((0, ux), (1, uy)) if abs(c) > 1e-12]
            out.append(_fault(FaultKind.LENGTH, i, "m", terms))
        if abs(p[2]) > MIN_LINK:
            out.append(_fault(FaultKind.OFFSET, i, "m", [FaultTerm(i, 2, 1.0)]))
    return tuple(out)


def effect_fault(effect) -> Fault:  # type: ignore[no-untyped-def]
    """The fault of an effect (``backlash:j2``, ``compliance:j3``, ``cyclic:j1:h11`` …): its
    parameter(s) changed or appeared."""
    try:  # the effect's declarations (identify/effects), never its name's spelling
        kind = FaultKind(effect.family)
    except ValueError:
        kind = FaultKind.OTHER
    joint = 0 if effect.joint is None else effect.joint + 1
    unit = effect.param_units[0] if effect.param_units else "1"
    words = None
    spectrum_bin = effect.spectrum_bin()
    if kind is FaultKind.OTHER:
        words = f"joint {joint} {effect.family}"
    elif spectrum_bin is not None:
        words = f"joint {joint} {effect.family} error ({spectrum_bin[1]} per turn)"
    elif effect.name != effect.physical:  # another form of the effect (compliance:j2:lumped)
        words = f"joint {joint} {effect.family} ({effect.form} form)"
    coords = tuple(f"{effect.name}.{p}" for p in effect.param_names)
    return _fault(kind, joint, unit, effect=effect.name, coordinates=coords, key=effect.name,
                  words=words)  # fmt: skip


#: The target's six coordinates on the flange (the tool's constant motions) and their words.
_SETUP_WORDS = {
    "dx": "target moved on the flange along x",
    "dy": "target moved on the flange along y",
    "dz": "target moved on the flange along z",
    "ex": "target turned on the flange about x",
    "ey": "target turned on the flange about y",
    "ez": "target turned on the flange about z",
}


def setup_faults() -> tuple[Fault, ...]:
    """The target moving on the flange (re-mounted, knocked), one tool coordinate each."""
    return tuple(
        _fault(FaultKind.SETUP, 0, "m" if m.startswith("d") else "rad",
               coordinates=(f"tool.{m}.c0",), key=f"tool.{m}", words=w)
        for m, w in _SETUP_WORDS.items()
    )  # fmt: skip


def fault_dictionary(robot, effects: Sequence = (), setup: bool = False) -> tuple[Fault, ...]:  # type: ignore[no-untyped-def]
    """Every geometric fault of ``robot``, the faults of ``effects`` (Effect objects) and,
    with ``setup``, the target's moves on the flange."""
    out = geometric_faults(robot) + tuple(effect_fault(e) for e in effects)
    return out + setup_faults() if setup else out


# --------------------------------------------------------------------------- columns


def fault_columns(faults: Sequence[Fault], q: F, Jmot: F) -> F:
    """Change of the measured pose per unit size of each geometric fault, (n, d, n_faults).

    Parameters
    ----------
    q : ndarray, shape (n, nj), rad
        Joint readings.
    Jmot : ndarray, shape (n, d, nf, 6)
        ∂pose/∂(six motions of every frame), frames 0 … nj + 1 (:func:`~.linearize.motion_jacobian`,
        whitened or not: the columns come out the same way).
    """
    n, d = Jmot.shape[:2]
    out = np.zeros((n, d, len(faults)))
    for k, f in enumerate(faults):
        for t in f.terms:
            prof = q[:, t.frame - 1] if t.profile == "angle" else 1.0
            out[:, :, k] += t.coef * Jmot[:, :, t.frame, t.motion] * np.reshape(prof, (-1, 1))
    return out


# --------------------------------------------------------------------------- images


@dataclass(frozen=True, eq=False)
class FaultImages:
    """Each fault as the change of a fitted model's parameters it causes (its gauge).

    ``G`` (n_labels, n_columns): a unit fault changes the fitted parameters ``labels`` by its
    columns (``columns[k]``: fault k's slice; one column for a geometric fault, one per
    parameter for an effect): least squares on the evaluation poses, whitened by the fit's
    noise model.  ``observable[k]``: the share (0 … 1, RMS over the poses) of the fault's
    effect on the measured poses that no change of base and tool takes up;
    ``represented[k]``: the share the model's free parameters express.  ``tcp[k]``: largest
    TCP displacement of a unit geometric fault over the evaluation poses, base and tool
    registered out (m per unit; NaN for the others).  ``transfer``: a change of any
    parameter (held ones too) as the change of the free ones that has the same effect on
    the evaluation poses (identity on the free ones): another fit's coefficients in this
    fit's gauge.
    """

    faults: tuple[Fault, ...]
    labels: tuple[str, ...]
    G: F
    columns: tuple[slice, ...]
    observable: F
    represented: F
    tcp: F
    transfer: F | None = None  # (n_labels, n_labels): any parameter change in this gauge

    def testable(self, min_observable: float = 0.02, min_represented: float = 0.5) -> list[int]:
        """Indices of the faults the data can see (not a set-up change of base and tool) and
        the model can express."""
        return [
            k
            for k in range(len(self.faults))
            if self.observable[k] > min_observable and self.represented[k] > min_represented
        ]

    def block(self, k: int, labels: Sequence[str]) -> F:
        """Fault ``k``'s columns on the parameters ``labels`` (zero where it has none)."""
        pos = {lb: i for i, lb in enumerate(self.labels)}
        cols = self.G[:, self.columns[k]]
        out = np.zeros((len(labels), cols.shape[1]))
        for r, lb in enumerate(labels):
            if lb in pos:
                out[r] = cols[pos[lb]]
        return out


def is_setup_label(label: str) -> bool:
    """Base and tool parameters: the instrument set-up, no part of the robot."""
    return label.startswith(("base.", "tool."))


def fault_images(fitted, faults: Sequence[Fault], meas) -> FaultImages:  # type: ignore[no-untyped-def]
    """Map every fault through ``fitted``'s gauge on the evaluation poses ``meas``.

    Parameters
    ----------
    fitted : FittedModel
    faults : sequence of Fault
    meas : Measurements
        The evaluation poses (their joint readings and per-row uncertainties are used, not
        their measured values): the baseline's own poses, or a grid in the common region.

    Returns
    -------
    FaultImages
    """
    from .fit import linearised  # the fit imports nothing of this module

    lin = linearised(fitted, meas)
    n, d = meas.n_poses, lin.d
    labels = list(fitted.labels)
    pos = {lb: i for i, lb in enumerate(labels)}
    out_ = set(fitted.unidentifiable) | set(fitted.held)
    free = np.array([lb not in out_ for lb in labels])
    base = np.array([lb.startswith("base.") for lb in labels])
    setup = np.array([is_setup_label(lb) for lb in labels])
    J = lin.J  # (n d, n_all) whitened model Jacobian
    nj = fitted.robot.n_joints
    Jmot = np.zeros((n, d, nj + 2, 6))  # every frame; no geometric fault lives in base or tool
    Jmot[:, :, 1:-1] = lin.J_motion
    geo = [f for f in faults if f.terms]
    Fg = fault_columns(geo, meas.q, Jmot).reshape(n * d, -1)
    columns, blocks, k_geo, start = [], [], 0, 0
    for f in faults:
        if f.terms:
            blocks.append(Fg[:, k_geo : k_geo + 1])
            k_geo += 1
        else:  # a parameter of the model: the fault is its own coordinate (zero if absent)
            cols = [J[:, pos[c]] if c in pos and free[pos[c]] else np.zeros(n * d)
                    for c in f.coordinates]  # fmt: skip
            blocks.append(np.stack(cols, axis=1))
        columns.append(slice(start, start + blocks[-1].shape[1]))
        start += blocks[-1].shape[1]
    Fall = np.concatenate(blocks, axis=1)
    sol, *_ = np.linalg.lstsq(J[:, free], Fall, rcond=None)
    G = np.zeros((len(labels), Fall.shape[1]))
    G[free] = sol
    for k, f in enumerate(faults):  # a model parameter is exactly its own coordinate
        if f.coordinates:
            G[:, columns[k]] = 0.0
            for c_i, c in enumerate(f.coordinates):
                if c in pos and free[pos[c]]:
                    G[pos[c], columns[k].start + c_i] = 1.0
    # what base and tool take up: the tool is a set-up change only for the geometric faults
    # (a set-up fault *is* a tool coordinate); the base always
    observable = np.zeros(len(faults))
    represented = np.zeros(len(faults))
    for k, f in enumerate(faults):
        Fk = Fall[:, columns[k]]
        nuis = free & (base if not f.terms else setup)
        Jn = J[:, nuis]
        Fo = Fk - Jn @ np.linalg.lstsq(Jn, Fk, rcond=None)[0] if Jn.shape[1] else Fk
        tot = float(np.sqrt(np.sum(Fk**2)))
        seen = float(np.sqrt(np.sum(Fo**2)))
        rem = float(np.sqrt(np.sum((Fk - J[:, free] @ G[free][:, columns[k]]) ** 2)))
        observable[k] = seen / tot if tot > 0 else 0.0
        represented[k] = max(0.0, 1.0 - rem / seen) if seen > 0 else 0.0
    transfer = np.zeros((len(labels), len(labels)))
    transfer[np.ix_(free, free)] = np.eye(int(free.sum()))
    if np.any(~free):
        transfer[np.ix_(free, ~free)] = np.linalg.lstsq(J[:, free], J[:, ~free], rcond=None)[0]
    return FaultImages(
        faults=tuple(faults),
        labels=tuple(labels),
        G=G,
        columns=tuple(columns),
        observable=observable,
        represented=represented,
        tcp=_tcp_sizes(fitted, faults, meas.q),
        transfer=transfer,
    )


def evaluation_poses(fitted, n: int = 300, seed: int = 0):  # type: ignore[no-untyped-def]
    """An evaluation set where no measured poses are at hand: ``n`` joint commands uniform
    over the model's ranges (fixed seed), the model's own prediction as their "measurement"
    and the model's noise defaults as their uncertainty."""
    from .measurements import Measurements
    from .transforms import R_to_rpy

    spec = fitted.spec
    q = np.random.default_rng(seed).uniform(spec.q_lo, spec.q_hi, (n, spec.n_joints))
    T = fitted.predict(q)
    rpy = R_to_rpy(T[:, :3, :3]) if fitted.has_orientation else None
    return Measurements(q=q, pos=T[:, :3, 3].copy(), rpy=rpy)


def _tcp_sizes(fitted, faults: Sequence[Fault], q: F) -> F:  # type: ignore[no-untyped-def]
    """Largest TCP displacement (m) per unit of each geometric fault over ``q``, after the
    best rigid registration of base and tool (the health figure's convention)."""
    from .linearize import forward, motion_jacobian
    from .transforms import skew

    T, A, mot = forward(
        fitted.robot, fitted.spec, fitted.coeffs, fitted.T_instr_base0, fitted.T_flange_target0, q
    )
    assert A is not None
    Jm = motion_jacobian(T, A, mot)[:, :3]  # (n, 3, nf, 6)
    geo = [f for f in faults if f.terms]
    Fg = fault_columns(geo, q, Jm)  # (n, 3, k)
    p = T[:, :3, 3]
    R = np.concatenate(
        [-skew(p), np.broadcast_to(np.eye(3), (len(q), 3, 3)), T[:, :3, :3]], axis=2
    ).reshape(-1, 9)
    flat = Fg.reshape(-1, Fg.shape[2])
    reg = flat - R @ np.linalg.lstsq(R, flat, rcond=None)[0]
    sizes = iter(np.max(np.linalg.norm(reg.reshape(Fg.shape), axis=1), axis=0))
    return np.array([float(next(sizes)) if f.terms else math.nan for f in faults])


# --------------------------------------------------------------------------- naming


@dataclass(frozen=True)
class Alternative:
    """A fault that explains the same change about as well (ambiguous geometry)."""

    fault: str
    words: str
    probability: float  # share of the evidence among the faults
    prior: float


@dataclass(frozen=True)
class NamedChange:
    """One change named by the physical fault that explains it (SI inside; see ``to_json``).

    ``size`` ± ``sigma`` in ``unit`` (SI); ``z = size / sigma``; ``p_value`` two-sided from
    ``z`` (the same z, σ and p in every line); ``significant``: the test's verdict
    (p below its Bonferroni level and the size above the practical minimum);
    ``probability``: the fault's share of the evidence among the faults tested;
    ``alternatives``: other faults that explain the change nearly as well, most likely
    first (equal evidence is ranked by :data:`PRIOR`).  ``tcp``: the largest TCP
    displacement the change causes (m), set-up registered out.
    """

    fault: str
    kind: str
    joint: int
    words: str
    size: float
    sigma: float
    unit: str
    z: float
    p_value: float
    significant: bool
    probability: float
    prior: float
    cause: str
    action: str
    tcp: float = math.nan
    alternatives: tuple[Alternative, ...] = ()
    source: str = "trend"  # "trend" or "check"

    @property
    def display_unit(self) -> str:
        """The unit people read (mrad, mm, ppm …)."""
        return DISPLAY.get(self.unit, (self.unit, 1.0))[0]

    @property
    def display_scale(self) -> float:
        """Factor from SI to :attr:`display_unit`."""
        return DISPLAY.get(self.unit, (self.unit, 1.0))[1]

    def size_words(self) -> str:
        """``+0.300 ± 0.010 mrad``: the size to the decimal of its σ's second digit, with at
        most four significant digits (``+0.5000 ± 0.0008 mrad``, not ``+0.5 ± 0.00079``)."""
        k = self.display_scale
        size, sigma = self.size * k, abs(self.sigma * k)
        dec = []
        if np.isfinite(sigma) and sigma > 0:
            dec.append(1 - int(np.floor(np.log10(sigma))))
        if np.isfinite(size) and size != 0:
            dec.append(3 - int(np.floor(np.log10(abs(size)))))
        d = max(min(dec), 0) if dec else 3
        return f"{size:+.{d}f} ± {sigma:.{d}f} {self.display_unit}"

    def line(self) -> str:
        """One line for people, technician first, statistics after: ``joint 2 zero offset
        changed by -0.300 ± 0.010 mrad (encoder or zero reference …; z = -30.0, p = 1e-197)``
        plus the alternatives geometry cannot tell apart."""
        s = f"{self.words} changed by {self.size_words()} ({self.cause}; {self.stats()})"
        alts = [a for a in self.alternatives if a.probability >= 0.01]
        if alts:
            s += "; or " + ", or ".join(
                f"{a.words} ({100 * a.probability:.0f} %)" for a in alts[:3]
            )
        return s

    def stats(self) -> str:
        """``z = -30.0, p = 1.2e-197``: z and p from the same numbers."""
        p = f"p = {self.p_value:.1e}" if self.p_value > 1e-300 else "p < 1e-300"
        return f"z = {self.z:+.1f}, {p}"

    def to_json(self) -> dict[str, object]:
        """check.json's and trend --json's change entry (display units at the boundary)."""
        k = self.display_scale
        return {
            "fault": self.fault,
            "kind": self.kind,
            "joint": self.joint,
            "words": self.words,
            "size": self.size * k,
            "sigma": self.sigma * k,
            "size_unit": self.display_unit,
            "z": self.z,
            "p_value": self.p_value,
            "significant": self.significant,
            "probability": self.probability,
            "tcp_mm": None if not math.isfinite(self.tcp) else self.tcp * 1e3,
            "cause": self.cause,
            "action": self.action,
            "alternatives": [
                {"fault": a.fault, "words": a.words, "probability": a.probability, "prior": a.prior}
                for a in self.alternatives
            ],  # fmt: skip
            "line": self.line(),
        }


__all__ = [
    "PRIOR",
    "Alternative",
    "Fault",
    "FaultImages",
    "FaultKind",
    "FaultTerm",
    "NamedChange",
    "effect_fault",
    "evaluation_poses",
    "fault_columns",
    "fault_dictionary",
    "fault_images",
    "geometric_faults",
    "is_setup_label",
    "setup_faults",
]
