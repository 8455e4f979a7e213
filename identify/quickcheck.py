"""The quick check: has the robot changed since its baseline?  A sequential test.

A fitted baseline (its model and covariance) predicts every pose the robot can be sent to.
The check measures poses one at a time and, after each, asks a sequential test whether the
data already decide between

- **H0, unchanged**: the robot is the baseline's (every measured pose is the baseline's
  prediction plus the instrument's noise, the baseline's own estimation error and a possibly
  moved set-up: base and tool), and
- **H1, changed**: one error motion of one joint (its Chebyshev series of orders
  ``0 … settings.order``), or one physical effect (backlash, compliance), changed by an amount
  that moves the TCP by at least ``settings.detect`` somewhere in the workspace,

at a false-alarm probability ``α`` and a miss probability ``β`` (power ``1 − β``).

The design: Wald's sequential probability ratio test with composite hypotheses
-----------------------------------------------------------------------------
Everything is linear-Gaussian around the baseline: a pose's residual (measured minus the
baseline's prediction, whitened by the fit's own noise model) is ``r = B δ + A η + e`` with
``e ~ N(0, I)``, ``η ~ N(0, P)`` the baseline's estimation error (its covariance) and the set-up
change (``setup_pos``, ``setup_rot`` per base and tool motion), and ``δ`` the change.  ``η``
is integrated out, so every likelihood below is exact for the stacked, correlated residuals
of all poses measured so far.  For a change ``δ`` of family ``j`` (``k ≤ 2`` parameters) the
log likelihood ratio against H0 is ``f_j(δ) = δᵀ s_j − ½ δᵀ I_j δ`` with the score ``s_j`` and
the information ``I_j`` of the family after ``η`` is integrated out.

- **"changed"** when the *mixture* likelihood ratio ``Λ = Σ_j w_j ∫ e^{f_j(δ)} π_j(δ) dδ + w_o Λ_o``
  reaches ``A = 1/α`` (Robbins' mixture SPRT, 1970): ``π_j`` an equal mixture of Gaussians
  whose typical change moves the TCP by 1, 4 and 16 times ``prior_scale · detect`` (root
  mean square over the workspace), and ``Λ_o``
  an *omnibus* alternative that lets every pose shift on its own (``N(0, τ²)`` per component,
  ``τ = detect`` in position, ``detect / 0.5 m`` in rotation): changes no family describes.
  Under H0, ``Λ`` is a non-negative martingale with mean 1 whatever poses are chosen, as long
  as each choice uses only the data before it; by Ville's inequality the probability that it
  *ever* reaches ``1/α`` is at most ``α``.
- **"unchanged"** when ``max_j sup_{δ ∈ H1_j} f_j(δ) ≤ log β`` (Wald's lower boundary
  ``B = β``, taken at the least favourable alternative): for the true change ``δ ∈ H1``,
  ``e^{-f(δ)}`` is a martingale with mean 1 under ``δ``, so the probability of ever calling
  it unchanged is at most ``β``.  ``H1_j`` is the set of changes of family ``j`` whose largest
  TCP displacement over the workspace sample (joint ranges of the model, base and tool
  registered out as in every health figure) is at least ``detect``; the supremum of the
  concave ``f_j`` over the outside of that convex set is found on its boundary (two points for
  one parameter, ``settings.directions`` for two).
- otherwise the next pose.

Both guarantees hold for any stopping time and any adaptive choice of poses (no
Bonferroni over looks, no maximum sample size), *under the model's assumptions*: Gaussian
noise with the baseline's noise model (the instrument's stated per-row uncertainties, plus
the scatter the baseline fit estimated), the loop linearised at the baseline's estimate
(changes of micrometres and microradians), the baseline covariance right (scaled by
``cov_scale``), and, for the power, a change of one family (a single fault).  Effects a
family does not describe can only be caught by the omnibus part, without a power guarantee.

Choosing the next pose: :func:`information_gains` is each candidate's gain in
``Σ_j ½ log det(Π_j⁻¹ + I_j)`` (Bayesian D-optimality of every family's change, with ``η``
integrated out); the caller divides it by the robot time the pose costs.

SYNOPSIS::

    model = change_model(fitted, CheckSettings())
    status = check_status(model, fitted, meas)        # meas: the check's poses, execution order
    status.decision, status.changes()
    gains = information_gains(model, fitted, meas, q_now, candidates)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from .effects import (
    CHANNELS,
    Effect,
    Perturbation,
    check_effects,
    check_kinds,
    effect_context,
    total_perturbation,
)
from .errormodel import MOTION_WORDS, MOTIONS, ErrorModelSpec
from .errors import InputError
from .faults import Alternative, Fault, NamedChange, effect_fault, geometric_faults
from .fit import FittedModel, linearised
from .linearize import (
    Whitening,
    coefficient_columns,
    effect_channels,
    effect_jacobian,
    forward,
    motion_jacobian,
    sensitivities,
)
from .measurements import Measurements
from .transforms import R_to_rpy, skew

F = NDArray[np.float64]

#: Lever (m) that turns the position prior of the omnibus alternative into a rotation.
OMNIBUS_LEVER = 0.5


class Decision(StrEnum):
    """What the sequential test says after the poses so far."""

    UNCHANGED = "unchanged"
    CHANGED = "changed"
    CONTINUE = "continue"


class FamilyKind(StrEnum):
    """A physical fault of the robot (:mod:`.faults`), a physical effect, or any change of a
    joint's error motion (its Chebyshev series: changes no single fault describes)."""

    FAULT = "fault"
    MOTION = "motion"
    EFFECT = "effect"


#: Share of a fault's TCP displacement the set-up must leave for the fault to be tested.
MIN_OBSERVABLE = 0.02
#: Prior weight of a change of a whole error-motion curve (no single fault; the faults'
#: weights are :data:`~.faults.PRIOR`).
CURVE_PRIOR = 0.5


@dataclass(frozen=True)
class CheckSettings:
    """The error rates and the models of the change (SI).

    Attributes
    ----------
    false_alarm : float
        ``α``: probability of calling an unchanged robot "changed".
    detect : float, m
        Smallest change to detect: its largest TCP displacement over the workspace.
    power : float
        ``1 − β``: probability of calling "changed" a robot whose change is at least ``detect``.
    order : int
        A changed error motion is a Chebyshev series of orders ``0 … order`` (0: constant).
    effects : tuple of str
        Effect kinds whose appearance (or change) on any joint is a family of its own
        (default: every kind an effect type declares, :func:`~.effects.check_kinds`).
    setup_pos, setup_rot : float, m and rad
        Prior standard deviation of a change of the instrument's set-up (every base motion)
        between the baseline and the check: a moved camera is no change of the robot.
    target_pos, target_rot : float, m and rad
        The same for the target on the flange (every tool motion).  The target stays mounted
        between a baseline and its checks, so it is held to the repeatability of a fixed
        mount: a target free to move would take up most of a wrist joint's zero offset (on
        the shared UR10 81 % of joint 5's); a re-mounted target is a change (measure a new
        baseline).
    cov_scale : float
        Factor on the baseline's covariance (fits understate their own scatter: docs/monitoring.md).
    omnibus_weight : float
        Weight of the omnibus alternative in the mixture (the families share the rest).
    prior_scale : float
        A family's prior: changes whose RMS TCP displacement is ``prior_scale · detect``.
    workspace_samples : int
        Joint commands (uniform over the model's ranges, fixed seed) the TCP size is taken over.
    directions : int
        Boundary points of a two-parameter family's ``H1``.
    """

    false_alarm: float = 0.01
    detect: float = 5e-5
    power: float = 0.95
    order: int = 1
    effects: tuple[str, ...] = field(default_factory=check_kinds)
    setup_pos: float = 0.01
    setup_rot: float = 0.01
    target_pos: float = 1e-5
    target_rot: float = 1e-5
    cov_scale: float = 1.0
    omnibus_weight: float = 0.2
    prior_scale: float = 1.0
    workspace_samples: int = 1000
    directions: int = 360

    def __post_init__(self) -> None:
        if not 0.0 < self.false_alarm < 0.5:
            raise InputError(f"false-alarm probability must be in (0, 0.5), got {self.false_alarm}")
        if not 0.5 < self.power < 1.0:
            raise InputError(f"power must be in (0.5, 1), got {self.power}")
        if not (math.isfinite(self.detect) and 1e-7 <= self.detect <= 1e-2):
            raise InputError(
                f"smallest change to detect must be 0.0001 … 10 mm, got {self.detect * 1e3:g} mm"
            )
        if self.order not in (0, 1):
            raise InputError(f"change order must be 0 or 1, got {self.order}")

    @property
    def log_a(self) -> float:
        """``log(1/α)``: the upper (changed) boundary of the log likelihood ratio."""
        return -math.log(self.false_alarm)

    @property
    def log_b(self) -> float:
        """``log β``: the lower (unchanged) boundary."""
        return math.log(1.0 - self.power)


@dataclass(frozen=True, eq=False)
class ChangeFamily:
    """One kind of change (a single fault): a joint's error motion or an effect.

    ``columns`` index the change vector's raw parameters (Chebyshev coefficients or effect
    parameters); ``basis`` (len(columns), k) maps the family's ``k`` coordinates that move the
    TCP (the rest is a set-up change) to them.  ``ws`` (n_ws, 3, k): registered TCP
    displacement per unit coordinate at every workspace sample.  ``boundary`` (n_b, k): the
    changes with largest TCP displacement exactly ``detect`` (the edge of ``H1``).
    """

    name: str
    kind: FamilyKind
    joint: int  # 1-based
    motion: str  # "dx" … "ez", or the effect kind ("backlash", "compliance")
    columns: NDArray[np.int64]
    basis: F
    prior: F  # (k, k)
    ws: F
    boundary: F
    unit: str  # "m" or "rad" (of the reported size)
    fault: Fault | None = None  # the physical fault the family is (faults and effects)
    direction: F | None = None  # (len(columns),): a fault's unit size in the raw columns

    @property
    def k(self) -> int:
        """Number of coordinates."""
        return int(self.basis.shape[1])

    @property
    def weight(self) -> float:
        """Prior weight in the mixture: how often such a change occurs (:data:`~.faults.PRIOR`)."""
        return self.fault.prior if self.fault is not None else CURVE_PRIOR

    def words(self) -> str:
        """E.g. ``joint 2 zero offset``, ``joint 2 backlash`` or, for a whole error-motion
        curve, ``joint 2 tilt about x curve``."""
        if self.fault is not None:
            return self.fault.words
        if self.kind is FamilyKind.MOTION:
            return f"joint {self.joint} {MOTION_WORDS[self.motion]} curve"
        return f"{self.motion} of joint {self.joint}"


@dataclass(frozen=True, eq=False)
class ChangeModel:
    """The families of change of one baseline, their priors and ``H1`` (:func:`change_model`)."""

    settings: CheckSettings
    spec: ErrorModelSpec  # the changed motions' orders (joints only)
    effects: tuple[Effect, ...]
    families: tuple[ChangeFamily, ...]
    eta: NDArray[np.int64]  # the baseline's parameters integrated out (indices into labels)
    P_eta: F  # their prior covariance: baseline covariance and set-up change
    d: int  # residual components per pose (6 or 3)
    orientation: bool
    pairs: dict[str, int] = field(default_factory=dict)  # pose id -> row of the baseline's data
    base_raw: F | None = None  # (n_b, d) the baseline's own residuals (measured − model)
    base_cov: F | None = None  # (n_b, d, d) their noise covariance
    #: Variance factor on the noise of a pose compared with the model's prediction (unpaired):
    #: the baseline fit's own χ²/dof with its noise model, at least 1 (1 when paired).
    noise_scale: float = 1.0

    @property
    def paired(self) -> bool:
        """True when each check pose is compared with the baseline's measurement of it."""
        return self.base_raw is not None

    @property
    def n_raw(self) -> int:
        """Raw change parameters: motion coefficients, then effect parameters."""
        return int(self.spec.n_params + sum(e.n_params for e in self.effects))

    @property
    def weights(self) -> F:
        """Mixture weight of every family, in proportion to its prior weight (the omnibus
        has ``settings.omnibus_weight``)."""
        w = np.array([f.weight for f in self.families], dtype=float)
        return (1.0 - self.settings.omnibus_weight) * w / max(float(w.sum()), 1e-300)


@dataclass(frozen=True)
class Change:
    """One family's estimated change after the check (SI).

    ``size``: largest change of the error motion over the joint's range (m or rad as
    ``unit``), for an effect its parameter; ``sigma``: its standard uncertainty; ``tcp``:
    the largest TCP displacement it causes over the workspace (m); ``probability``: the
    family's share of the evidence for a change; ``log_lr``: its own log mixture likelihood
    ratio.
    """

    family: str
    joint: int
    motion: str
    words: str
    size: float
    sigma: float
    unit: str
    tcp: float
    probability: float
    log_lr: float
    fault: Fault | None = None

    def named(self, alternatives: tuple[Alternative, ...] = ()) -> NamedChange:
        """The change as every door names it (:class:`~.faults.NamedChange`): z from the
        size and its σ, p from z."""
        from .fault_test import two_sided_p

        z = self.size / self.sigma if self.sigma > 0 else math.inf
        f = self.fault
        kind = f.kind.value if f is not None else "curve"
        cause = (
            f.cause
            if f is not None
            else "a change of the joint's error motion no single fault describes"
        )
        action = f.action if f is not None else "run a full assessment"
        return NamedChange(
            fault=self.family, kind=kind, joint=self.joint, words=self.words, size=self.size,
            sigma=self.sigma, unit=self.unit, z=z, p_value=two_sided_p(z), significant=True,
            probability=self.probability, prior=f.prior if f is not None else CURVE_PRIOR,
            cause=cause, action=action, tcp=self.tcp, alternatives=alternatives, source="check",
        )  # fmt: skip


@dataclass(frozen=True, eq=False)
class CheckStatus:
    """The sequential test after ``n_poses`` poses (:func:`check_status`)."""

    model: ChangeModel
    n_poses: int
    decision: Decision
    log_lr: float  # log mixture likelihood ratio (changed boundary: settings.log_a)
    log_lr_families: F  # (n_families,)
    log_lr_omnibus: float
    log_sup_h1: float  # max over families of sup_{H1} f (unchanged boundary: settings.log_b)
    sup_h1_families: F  # (n_families,)
    estimates: tuple[F, ...]  # per family: posterior mean of its coordinates
    covariances: tuple[F, ...]  # per family: posterior covariance
    chi2: float  # whitened residual sum of squares with η integrated out
    dof: int

    @property
    def weakest(self) -> str:
        """The family that keeps the check from calling "unchanged"."""
        return self.model.families[int(np.argmax(self.sup_h1_families))].name

    @property
    def omnibus_probability(self) -> float:
        """The omnibus alternative's share of the evidence for a change: a change no family
        describes (every pose shifted its own way)."""
        w = self.model.weights
        logs = np.log(np.maximum(w, 1e-300)) + self.log_lr_families
        o = math.log(self.model.settings.omnibus_weight) + self.log_lr_omnibus
        top = max(float(logs.max(initial=-np.inf)), o)
        return float(math.exp(o - top) / (np.exp(logs - top).sum() + math.exp(o - top)))

    def changes(self, min_probability: float = 0.05) -> list[Change]:
        """The families that explain the evidence for a change, most likely first."""
        fams = self.model.families
        w = self.model.weights
        logs = np.log(np.maximum(w, 1e-300)) + self.log_lr_families
        o = math.log(self.model.settings.omnibus_weight) + self.log_lr_omnibus
        top = max(float(logs.max(initial=-np.inf)), o)
        den = float(np.exp(logs - top).sum() + math.exp(o - top))
        prob = np.exp(logs - top) / den
        out = []
        for i in np.argsort(-prob):
            if prob[i] < min_probability:
                break
            out.append(_change(fams[i], self.estimates[i], self.covariances[i], prob[i],
                               self.log_lr_families[i]))  # fmt: skip
        return out

    def named_changes(self, min_probability: float = 0.05) -> list[NamedChange]:
        """:meth:`changes` as every door names them (:class:`~.faults.NamedChange`), each
        with the families that explain the evidence nearly as well (ambiguous geometry is
        ranked by the prior weights)."""
        ch = self.changes(min_probability=0.001)
        out = []
        for i, c in enumerate(ch):
            if c.probability < min_probability:
                break
            alts = tuple(
                Alternative(o.family, o.words, o.probability,
                            o.fault.prior if o.fault is not None else CURVE_PRIOR)
                for o in ch[i + 1 :]
            )  # fmt: skip
            out.append(c.named(alts))
        return out


def _change(fam: ChangeFamily, est: F, cov: F, prob: float, log_lr: float) -> Change:
    raw = fam.basis @ est
    raw_cov = fam.basis @ cov @ fam.basis.T
    if fam.direction is not None:  # a fault: its size along its own unit direction
        g = fam.direction / float(fam.direction @ fam.direction)
        size = float(g @ raw)
        sigma = float(np.sqrt(max(g @ raw_cov @ g, 0.0)))
    elif fam.kind is FamilyKind.MOTION and raw.size == 2:
        # the series c0 + c1·u over u ∈ [-1, 1]: largest at the end where |c0 + c1 u| peaks
        u = 1.0 if raw[0] * raw[1] >= 0 else -1.0
        g = np.array([1.0, u])
        size = float(g @ raw)
        sigma = float(np.sqrt(max(g @ raw_cov @ g, 0.0)))
    else:
        size, sigma = float(raw[0]), float(np.sqrt(max(raw_cov[0, 0], 0.0)))
    tcp = float(np.max(np.linalg.norm(fam.ws @ est, axis=1)))
    return Change(fam.name, fam.joint, fam.motion, fam.words(), size, sigma, fam.unit, tcp,
                  float(prob), float(log_lr), fam.fault)  # fmt: skip


# --------------------------------------------------------------------------- the change model


def change_model(
    fitted: FittedModel,
    settings: CheckSettings = CheckSettings(),
    baseline: Measurements | None = None,
) -> ChangeModel:
    """Families of change of the baseline ``fitted``, their priors and ``H1`` boundaries.

    With ``baseline`` (the measurements the model was fitted to, with their pose ids) the
    check is *paired*: a pose the baseline measured is compared with that measurement, the
    residual of the check's measurement against the model minus the baseline's own residual
    there.  What the model does not describe at that pose (its model error) and the model's
    estimation error cancel; the two measurements' noise adds.  Only poses with a baseline
    measurement can then be checked.  Without it every pose is compared with the model's
    prediction, whose covariance (``cov_scale`` times the fit's) is integrated out, and each
    pose's noise is the baseline's noise model scaled by the fit's own χ²/dof (at least 1,
    :attr:`ChangeModel.noise_scale`): the scatter estimator sets the tails of a real robot's
    residuals aside, so its noise model understates their mean square (the shared UR10's
    sessions: χ²/dof 1.10), and a few hundred poses compared with the model then read as a
    change no family describes (the omnibus), though the robot is the same.

    Raises
    ------
    InputError
        The baseline needs a temperature the check does not measure (``thermal``).
    """
    for e in fitted.effects:  # a check passes the approach and the time, no other condition
        if set(e.requires()) - {"approach", "time"}:
            raise InputError(
                f"the baseline model has {e.name}, which needs the "
                f"{', '.join(CHANNELS[c].words for c in e.requires() if c != 'approach')}: a "
                "check measures none of it; use a baseline fitted without it"
            )
    robot = fitted.robot
    nj = robot.n_joints
    orders = np.full((nj + 2, 6), -1, dtype=np.int64)
    orders[1:-1] = settings.order
    spec = ErrorModelSpec(orders, fitted.spec.q_lo, fitted.spec.q_hi)
    effects = tuple(_effect_families(settings.effects, robot))
    rng = np.random.default_rng(0)
    q_ws = rng.uniform(spec.q_lo, spec.q_hi, (settings.workspace_samples, nj))
    G, R = _raw_columns(fitted, spec, effects, q_ws, np.ones_like(q_ws), None, 3, True)
    # a change base and tool can take up is a set-up change, no change of the robot: the
    # registration's columns from the same loop, so a set-up direction cancels to rounding
    R = R.reshape(-1, 9)
    Gf = G.reshape(-1, G.shape[-1])
    Greg = (Gf - R @ np.linalg.lstsq(R, Gf, rcond=None)[0]).reshape(G.shape)
    fams = []
    # the physical faults first (the same dictionary the trend names changes by), then any
    # change of a whole error-motion curve (what no single fault describes)
    for f in geometric_faults(robot):
        try:
            rv = f.raw_vector(spec)
        except ValueError:  # a joint scale in a constant-only change model
            continue
        cols = np.flatnonzero(rv)
        fam = _family(f.key, FamilyKind.FAULT, f.joint, f.kind.value, cols, G, Greg, settings,
                      f.unit, direction=rv[cols], fault=f)  # fmt: skip
        if fam is not None:
            fams.append(fam)
    idx = spec.index()
    for j in range(1, nj + 1):
        for m, mot in enumerate(MOTIONS):
            cols = np.flatnonzero((idx[:, 0] == j) & (idx[:, 1] == m))
            fam = _family(f"j{j}.{mot}", FamilyKind.MOTION, j, mot, cols, G, Greg, settings,
                          "m" if m < 3 else "rad")  # fmt: skip
            if fam is not None:
                fams.append(fam)
    pos = spec.n_params
    for e in effects:
        cols = np.arange(pos, pos + e.n_params)
        pos += e.n_params
        family = e.check_family
        assert family is not None and e.joint is not None, e.name
        # a jump's size (a backlash's: between the two approach directions) is the TCP jump
        # between the two states: no set-up change takes up a shift whose sign follows them
        g_reg = 2.0 * G if family.jump else Greg
        fam = _family(e.name, FamilyKind.EFFECT, e.joint + 1, family.kind, cols, G, g_reg,
                      settings, e.param_units[0], fault=effect_fault(e))  # fmt: skip
        if fam is not None:
            fams.append(fam)
    labels = fitted.labels
    setup = np.array([lb.startswith(("base.", "tool.")) for lb in labels])
    add = np.array([_setup_prior(lb, settings) ** 2 for lb in labels])
    pairs: dict[str, int] = {}
    base_raw = base_cov = None
    noise_scale = 1.0
    if baseline is not None:
        if baseline.pose_id is None:
            raise InputError(
                "the baseline's measurements have no pose ids: a paired check needs them"
            )
        m = _for_model(fitted, baseline)
        lin = linearised(fitted, m)
        L = np.linalg.inv(lin.W)
        base_raw = (L @ lin.r.reshape(m.n_poses, lin.d)[..., None])[..., 0]
        base_cov = lin.cov
        pairs = {pid: i for i, pid in enumerate(m.pose_id or ())}
        eta = np.flatnonzero(setup)
        P = np.diag(add[eta])
    else:
        out = set(fitted.unidentifiable) | set(fitted.held)
        eta = np.flatnonzero(np.array([lb not in out for lb in labels]) | setup)
        C = np.asarray(fitted.cov, float)[np.ix_(eta, eta)] * settings.cov_scale
        P = C + np.diag(np.where(setup[eta], add[eta], 0.0))
        noise_scale = max(1.0, float(fitted.chi2_data) / max(int(fitted.dof), 1))
    P = 0.5 * (P + P.T) + np.eye(len(eta)) * 1e-30
    return ChangeModel(
        settings=settings,
        spec=spec,
        effects=effects,
        families=tuple(fams),
        eta=eta,
        P_eta=P,
        d=6 if fitted.has_orientation else 3,
        orientation=fitted.has_orientation,
        pairs=pairs,
        base_raw=base_raw,
        base_cov=base_cov,
        noise_scale=noise_scale,
    )


def _setup_prior(label: str, s: CheckSettings) -> float:
    """Prior σ of a set-up change of parameter ``label`` (base: the instrument; tool: the
    target on the flange)."""
    rot = label.split(".")[1].startswith("e")
    if label.startswith("tool."):
        return s.target_rot if rot else s.target_pos
    return s.setup_rot if rot else s.setup_pos


def _effect_families(kinds: tuple[str, ...], robot) -> list[Effect]:  # type: ignore[no-untyped-def]
    """The effects of the families ``kinds``, as each effect type declares its quick-check
    family (:func:`~quickhealth.identify.effects.check_effects`)."""
    return check_effects(kinds, robot)


def _family(
    name: str,
    kind: FamilyKind,
    joint: int,
    motion: str,
    cols: NDArray[np.int64],
    G: F,
    Greg: F,
    settings: CheckSettings,
    unit: str,
    direction: F | None = None,
    fault: Fault | None = None,
) -> ChangeFamily | None:
    """The family of raw columns ``cols`` (along ``direction`` in them: a fault), reduced to
    the coordinates that move the TCP (None when none does: a set-up change).  A direction
    whose TCP displacement a set-up change takes up to a millionth of itself is a set-up
    change."""
    D = np.eye(len(cols)) if direction is None else np.asarray(direction, float)[:, None]
    g = Greg[:, :, cols] @ D  # (n_ws, 3, k_raw)
    n_ws = g.shape[0]
    M = np.einsum("nik,nil->kl", g, g) / n_ws  # mean squared TCP displacement metric
    g0 = G[:, :, cols] @ D
    scale = float(np.linalg.eigvalsh(np.einsum("nik,nil->kl", g0, g0) / n_ws).max())
    w, V = np.linalg.eigh(M)
    # a fault is seen when more than 2 % of its TCP displacement (RMS) is left after the
    # set-up's registration (:meth:`~.faults.FaultImages.testable`, the trend's rule)
    floor = (MIN_OBSERVABLE**2 if direction is not None else 1e-12) * max(scale, 1e-300)
    keep = w > floor
    if not np.any(keep):
        return None
    V = V[:, keep]
    w = w[keep]
    # coordinates: unit RMS TCP displacement each, orthogonal in that metric
    basis = V / np.sqrt(w)[None, :]
    ws = g @ basis  # (n_ws, 3, k)
    k = basis.shape[1]
    prior = np.eye(k) * (settings.prior_scale * settings.detect) ** 2 / k
    if k == 1:
        h = float(np.max(np.linalg.norm(ws[:, :, 0], axis=1)))
        boundary = np.array([[settings.detect / h], [-settings.detect / h]])
    else:
        phi = np.linspace(0.0, 2 * np.pi, settings.directions, endpoint=False)
        dirs = np.stack([np.cos(phi), np.sin(phi)], axis=1)  # (n_b, 2)
        if k > 2:  # pragma: no cover - order ≤ 1 gives at most two coordinates
            raise ValueError("a family has at most two coordinates")
        h = np.max(np.linalg.norm(np.einsum("nik,bk->bni", ws, dirs), axis=2), axis=1)
        boundary = settings.detect * dirs / h[:, None]
    return ChangeFamily(name, kind, joint, motion, cols, D @ basis, prior, ws, boundary, unit,
                        fault, None if direction is None else D[:, 0])  # fmt: skip


def _raw_columns(
    fitted: FittedModel,
    spec: ErrorModelSpec,
    effects: tuple[Effect, ...],
    q: F,
    approach: F,
    time: F | None,
    d: int,
    registration: bool = False,
) -> F | tuple[F, F]:
    """∂(model pose)/∂(change parameters) at joints ``q``, (n, d, n_raw): the changed motions'
    Chebyshev coefficients and the effect families' parameters, at the baseline's estimate.

    With ``registration`` also the target position's derivative (n, 3, 9) by a set-up change
    (base rotation about the instrument origin, base translation, tool point) from the same loop."""
    robot = fitted.robot
    ctx = effect_context(robot, q, approach, time, None)
    pert = (
        total_perturbation(fitted.effects, fitted.effect_params, ctx)
        if fitted.effects
        else Perturbation()
    )
    T, A, mot = forward(
        robot, fitted.spec, fitted.coeffs, fitted.T_instr_base0, fitted.T_flange_target0, q, pert
    )
    assert A is not None
    Jmot = motion_jacobian(T, A, mot, pert.instr_scale_z)[:, :d]
    cols = [coefficient_columns(spec, q, Jmot)]
    if effects:
        sens = sensitivities(
            robot,
            fitted.spec,
            fitted.coeffs,
            fitted.T_instr_base0,
            fitted.T_flange_target0,
            q,
            pert,
            channels=effect_channels(effects, ctx),
            loop=(T, A, mot),
        )
        cols += [effect_jacobian(e, ctx, sens)[:, :d] for e in effects]
    out = np.concatenate(cols, axis=-1)
    if not registration:
        return out
    p = T[:, :3, 3]
    R = np.concatenate([-skew(p), np.broadcast_to(np.eye(3), (len(q), 3, 3)), T[:, :3, :3]], axis=2)
    return out, R


# --------------------------------------------------------------------------- the data


@dataclass(frozen=True, eq=False)
class _Rows:
    """Whitened rows of poses: residual ``r`` (n, d), baseline/set-up columns ``A`` (n, d, m),
    change coordinates ``B`` (n, d, K) (every family's coordinates side by side) and the
    whitening ``W`` (n, d, d)."""

    r: F
    A: F
    B: F
    W: F


def _for_model(fitted: FittedModel, meas: Measurements) -> Measurements:
    """The check's measurements as the baseline model reads them: position only for a
    position-only baseline; a drifting instrument of the baseline held at its end."""
    if fitted.has_orientation and not meas.has_orientation:
        raise InputError(
            "the baseline was fitted to full poses (7D) but the check measured positions only"
        )
    m = meas if fitted.has_orientation else meas.position_only()
    if any("time" in e.requires() for e in fitted.effects):
        m = replace(m, time=np.full(m.n_poses, float(fitted.reference_time or 0.0)))
    return replace(m, temp=None)


def _rows(model: ChangeModel, fitted: FittedModel, meas: Measurements) -> _Rows:
    m = _for_model(fitted, meas)
    lin = linearised(fitted, m)
    n, d = m.n_poses, lin.d
    L = np.linalg.inv(lin.W)
    raw_r = (L @ lin.r.reshape(n, d)[..., None])[..., 0]
    raw_A = (L @ lin.J.reshape(n, d, -1))[:, :, model.eta]
    cov = lin.cov
    if model.paired:
        assert model.base_raw is not None and model.base_cov is not None
        idx = pair_rows(model, m)
        raw_r = raw_r - model.base_raw[idx]
        cov = cov + model.base_cov[idx]
    W = Whitening.of(cov * model.noise_scale).W
    raw = _raw_columns(fitted, model.spec, model.effects, m.q, m.approach_sign(), m.time, d)
    assert isinstance(raw, np.ndarray)
    raw = np.matmul(W, raw)
    B = np.concatenate([raw[:, :, f.columns] @ f.basis for f in model.families], axis=2)
    r = np.matmul(W, raw_r[..., None])[..., 0]
    return _Rows(r, np.matmul(W, raw_A), B, W)


def pair_rows(model: ChangeModel, meas: Measurements) -> NDArray[np.int64]:
    """The baseline's row of every pose of ``meas`` (paired check; by pose id).

    Raises
    ------
    InputError
        A pose the baseline did not measure.
    """
    ids = meas.pose_id or ()
    missing = [p for p in ids if p not in model.pairs]
    if missing or len(ids) != meas.n_poses:
        raise InputError(
            f"pose {missing[0] if missing else '?'}: the baseline did not measure it, a "
            "paired check cannot compare it"
        )
    return np.array([model.pairs[p] for p in ids], dtype=np.int64)


def _family_slices(model: ChangeModel) -> list[slice]:
    out, pos = [], 0
    for f in model.families:
        out.append(slice(pos, pos + f.k))
        pos += f.k
    return out


# --------------------------------------------------------------------------- the test


def check_status(model: ChangeModel, fitted: FittedModel, meas: Measurements) -> CheckStatus:
    """The sequential test on the check's measured poses ``meas`` (execution order)."""
    s = model.settings
    rows = _rows(model, fitted, meas)
    n, d = rows.r.shape
    r = rows.r.reshape(-1)
    A = rows.A.reshape(n * d, -1)
    B = rows.B.reshape(n * d, -1)
    Pinv = _spd_inv(model.P_eta)
    Fe = Pinv + A.T @ A
    Le = np.linalg.cholesky(Fe)
    Fed = A.T @ B
    ue = A.T @ r
    Z = _chol_solve(Le, np.column_stack([Fed, ue]))
    Zd, Zu = Z[:, :-1], Z[:, -1]
    Info = B.T @ B - Fed.T @ Zd
    Info = 0.5 * (Info + Info.T)
    score = B.T @ r - Fed.T @ Zu
    q0 = float(r @ r - ue @ Zu)
    logdet0 = 2.0 * float(np.sum(np.log(np.diag(Le))))
    fams = model.families
    sl = _family_slices(model)
    lam = np.empty(len(fams))
    sup = np.empty(len(fams))
    est, covs = [], []
    for i, (fam, sli) in enumerate(zip(fams, sl, strict=True)):
        I_j = Info[sli, sli]
        s_j = score[sli]
        lam[i], m_j, c_j = _mixture(I_j, s_j, fam.prior)
        sup[i] = _sup_h1(I_j, s_j, fam, s.detect)
        est.append(m_j)
        covs.append(c_j)
    lo = _omnibus(model, rows, Pinv, q0, logdet0)
    w = model.weights
    terms = np.concatenate([np.log(np.maximum(w, 1e-300)) + lam, [math.log(s.omnibus_weight) + lo]])
    top = float(terms.max())
    log_lr = top + math.log(float(np.exp(terms - top).sum()))
    log_sup = float(sup.max()) if sup.size else -np.inf
    if log_lr >= s.log_a:
        decision = Decision.CHANGED
    elif log_sup <= s.log_b:
        decision = Decision.UNCHANGED
    else:
        decision = Decision.CONTINUE
    return CheckStatus(
        model=model,
        n_poses=n,
        decision=decision,
        log_lr=log_lr,
        log_lr_families=lam,
        log_lr_omnibus=lo,
        log_sup_h1=log_sup,
        sup_h1_families=sup,
        estimates=tuple(est),
        covariances=tuple(covs),
        chi2=q0,
        dof=int(n * d),
    )


#: Scales of a family's prior, equally weighted: changes of about the detectable size, and
#: 4 and 16 times larger (a large change would otherwise sit in the tail of a prior sized for
#: the smallest one, and the omnibus would explain it better than its own family).
PRIOR_SCALES = (1.0, 4.0, 16.0)


def _mixture(I_j: F, s_j: F, prior: F) -> tuple[float, F, F]:
    """log ∫ e^{f(δ)} π(δ) dδ for the scale mixture π of ``N(0, c² Π)`` over
    :data:`PRIOR_SCALES`, and the posterior mean and covariance of δ under its most likely
    scale."""
    parts = [_gaussian_mixture(I_j, s_j, prior * c * c) for c in PRIOR_SCALES]
    logs = np.array([p[0] for p in parts])
    top = float(logs.max())
    log_lam = top + math.log(float(np.exp(logs - top).mean()))
    best = parts[int(np.argmax(logs))]
    return log_lam, best[1], best[2]


def _gaussian_mixture(I_j: F, s_j: F, prior: F) -> tuple[float, F, F]:
    """log ∫ e^{f(δ)} N(δ; 0, Π) dδ and the posterior mean and covariance of δ."""
    k = s_j.size
    Ph = np.linalg.cholesky(prior)
    M = np.eye(k) + Ph.T @ I_j @ Ph
    Lm = np.linalg.cholesky(0.5 * (M + M.T))
    v = np.linalg.solve(Lm, Ph.T @ s_j)
    log_lam = -float(np.sum(np.log(np.diag(Lm)))) + 0.5 * float(v @ v)
    Minv = _chol_solve(Lm, np.eye(k))
    cov = Ph @ Minv @ Ph.T
    mean = cov @ s_j
    return log_lam, mean, cov


def _sup_h1(I_j: F, s_j: F, fam: ChangeFamily, detect: float) -> float:
    """sup of ``f(δ) = δᵀs − ½ δᵀIδ`` over the changes of the family with largest TCP
    displacement at least ``detect``."""
    b = fam.boundary
    f_b = b @ s_j - 0.5 * np.einsum("bi,ij,bj->b", b, I_j, b)
    best = float(f_b.max())
    # the unconstrained maximum, if it lies in H1 (or I is singular: then it always does)
    w, V = np.linalg.eigh(I_j)
    tol = 1e-9 * max(float(w.max()), 1e-300)
    if float(w.min()) <= tol:
        return max(best, 0.5 * float(np.sum((V.T @ s_j)[w > tol] ** 2 / w[w > tol])))
    dhat = V @ ((V.T @ s_j) / w)
    if float(np.max(np.linalg.norm(fam.ws @ dhat, axis=1))) >= detect:
        return max(best, 0.5 * float(s_j @ dhat))
    return best


def _omnibus(model: ChangeModel, rows: _Rows, Pinv: F, q0: float, logdet0: float) -> float:
    """log likelihood ratio of "every pose shifted on its own" against H0."""
    s = model.settings
    d = rows.r.shape[1]
    tau = np.r_[[s.detect] * 3, [s.detect / OMNIBUS_LEVER] * 3][:d]
    S = np.eye(d) + rows.W @ (tau[:, None] ** 2 * np.swapaxes(rows.W, -1, -2))  # (n, d, d)
    L = np.linalg.cholesky(S)
    r1 = np.linalg.solve(L, rows.r[..., None])[..., 0]
    A1 = np.linalg.solve(L, rows.A)
    n = r1.shape[0]
    r1 = r1.reshape(-1)
    A1 = A1.reshape(n * d, -1)
    Fe = Pinv + A1.T @ A1
    Le = np.linalg.cholesky(Fe)
    u = A1.T @ r1
    q1 = float(r1 @ r1 - u @ _chol_solve(Le, u))
    logdet1 = 2.0 * float(np.sum(np.log(np.diag(Le)))) + 2.0 * float(
        np.sum(np.log(np.einsum("nii->ni", L)))
    )
    return -0.5 * (q1 - q0) - 0.5 * (logdet1 - logdet0)


# --------------------------------------------------------------------------- a check as it runs

#: Evidence one family must hold before a "changed" check stops (the poses after the
#: decision only name the change).
NAME_PROBABILITY = 0.9
#: Poses a check may add after its decision to name the change (or as many as it took to
#: decide, if more).
NAMING_POSES = 6


class CheckRun:
    """The test as the poses come in: the first boundary crossed is the decision (the
    guarantees are about the first crossing: later poses, measured to name a change, never
    undo it), and when to stop (:meth:`stop_reason`)."""

    def __init__(self, model: ChangeModel, fitted: FittedModel) -> None:
        self.model = model
        self.fitted = fitted
        self.status: CheckStatus | None = None
        self.decision: tuple[Decision, int] | None = None  # and after how many poses
        self.scanned = 0

    def update(self, meas: Measurements | None) -> None:
        """The test after every pose of ``meas`` (execution order, growing call by call)."""
        if meas is None:
            return
        if meas.n_poses < self.scanned:  # pragma: no cover - the data only grow
            self.scanned, self.decision = 0, None
        for n in range(self.scanned + 1, meas.n_poses + 1):
            sub = meas if n == meas.n_poses else meas.subset(slice(0, n))
            st = check_status(self.model, self.fitted, sub)
            if self.decision is None and st.decision is not Decision.CONTINUE:
                self.decision = (st.decision, n)
            self.status = st
        self.scanned = max(self.scanned, meas.n_poses)

    @property
    def verdict(self) -> Decision:
        """CHANGED, UNCHANGED, or CONTINUE (not decided yet)."""
        return Decision.CONTINUE if self.decision is None else self.decision[0]

    def stop_reason(self, name_probability: float = NAME_PROBABILITY) -> str | None:
        """Why the check can stop now, or None: "unchanged" at once; "changed" once one
        family holds ``name_probability`` of the evidence."""
        if self.decision is None or self.status is None:
            return None
        if self.decision[0] is Decision.UNCHANGED:
            return "decided: unchanged"
        ch = self.status.changes()
        if ch and ch[0].probability >= name_probability:
            return f"decided: changed ({ch[0].words})"
        if self.status.omnibus_probability >= name_probability:
            return "decided: changed (no single joint motion or effect describes it)"
        after = self.status.n_poses - self.decision[1]
        if after >= max(self.decision[1], NAMING_POSES):
            return "decided: changed (not named within the naming poses)"
        return None


# --------------------------------------------------------------------------- choosing poses


def information_gains(
    model: ChangeModel,
    fitted: FittedModel,
    meas: Measurements | None,
    q_now: F,
    candidates: Measurements,
) -> F:
    """Gain of each candidate pose in ``Σ_j ½ log det(Π_j⁻¹ + I_j)`` if it were measured next.

    Parameters
    ----------
    meas : Measurements or None
        The check's poses so far (execution order).
    q_now : ndarray (nj,), rad
        Where the robot is (each candidate's approach directions are from here).
    candidates : Measurements
        One row per candidate pose: its joints and its expected noise (per-row uncertainties,
        e.g. those of the baseline's measurement of the same pose); the measured values are
        not used.

    Returns
    -------
    ndarray (n_candidates,), nats
    """
    nc = candidates.n_poses
    pred = _predicted(fitted, candidates)
    # each candidate right after the pose the robot is at: its approach directions from there
    here = replace(pred, q=np.broadcast_to(np.asarray(q_now, float), pred.q.shape).copy())
    both = _interleave(here, pred)
    rows2 = _rows(model, fitted, both)
    crow = _Rows(rows2.r[1::2], rows2.A[1::2], rows2.B[1::2], rows2.W[1::2])
    d = crow.r.shape[1]
    Pinv = _spd_inv(model.P_eta)
    if meas is not None and meas.n_poses:
        rows = _rows(model, fitted, meas)
        n = rows.r.shape[0]
        A = rows.A.reshape(n * d, -1)
        B = rows.B.reshape(n * d, -1)
    else:
        A = np.zeros((0, model.eta.size))
        B = np.zeros((0, crow.B.shape[2]))
    Fe = Pinv + A.T @ A
    Fi = _spd_inv(Fe)
    Fed = A.T @ B
    Fdd = B.T @ B
    Y = Fi @ Fed  # (m, K)
    base = Fdd - Fed.T @ Y
    Ac, Bc = crow.A, crow.B  # (nc, d, m), (nc, d, K)
    a = Ac @ Fi  # (nc, d, m)
    aF = a @ Fed  # (nc, d, K)
    G = a @ np.swapaxes(Ac, 1, 2)  # (nc, d, d)
    BtB = np.swapaxes(Bc, 1, 2) @ Bc
    cross = np.swapaxes(aF, 1, 2) @ Bc
    EFE = Fed.T @ Y + cross + np.swapaxes(cross, 1, 2) + np.swapaxes(Bc, 1, 2) @ G @ Bc
    aE = Ac @ Y + G @ Bc  # (nc, d, K)
    S = np.eye(d) + G
    corr = np.swapaxes(aE, 1, 2) @ np.linalg.solve(S, aE)
    Inew = Fdd + BtB - EFE + corr  # (nc, K, K)
    gains = np.zeros(nc)
    for fam, sli in zip(model.families, _family_slices(model), strict=True):
        Pi = _spd_inv(fam.prior)
        before = np.linalg.slogdet(Pi + base[sli, sli])[1]
        after = np.linalg.slogdet(Pi[None] + Inew[:, sli, sli])[1]
        gains += 0.5 * (after - before)
    return gains


def _predicted(fitted: FittedModel, cand: Measurements) -> Measurements:
    """``cand`` with the baseline's predicted pose as its "measurement" (residual zero)."""
    m = _for_model(fitted, cand)
    T = fitted.predict(m.q, time=m.time)
    if not m.has_orientation:
        return replace(m, pos=T[:, :3, 3].copy())
    rpy = R_to_rpy(T[:, :3, :3])
    return replace(m, pos=T[:, :3, 3].copy(), rpy=rpy, rot=None)


def _interleave(a: Measurements, b: Measurements) -> Measurements:
    """Rows ``a0, b0, a1, b1, …`` (same columns)."""
    n = a.n_poses
    order = np.empty(2 * n, dtype=np.int64)
    order[0::2] = np.arange(n)
    order[1::2] = np.arange(n) + n

    def cat(x, y):  # type: ignore[no-untyped-def]
        return None if x is None else np.concatenate([x, y])[order]

    return replace(
        a,
        q=cat(a.q, b.q),
        pos=cat(a.pos, b.pos),
        rpy=cat(a.rpy, b.rpy),
        rot=None if a.rpy is not None else cat(a.rot, b.rot),
        time=cat(a.time, b.time),
        temp=None,
        pan=cat(a.pan, b.pan),
        sigma_pos=cat(a.sigma_pos, b.sigma_pos),
        sigma_rpy=cat(a.sigma_rpy, b.sigma_rpy),
        sigma_rot=cat(a.sigma_rot, b.sigma_rot),
        pose_id=None
        if a.pose_id is None
        else tuple(np.repeat(np.asarray(b.pose_id, dtype=object), 2)),
        excluded=None,
    )


# --------------------------------------------------------------------------- small helpers


def _chol_solve(L: F, b: F) -> F:
    return np.linalg.solve(L.T, np.linalg.solve(L, b))


def _spd_inv(P: F) -> F:
    L = np.linalg.cholesky(0.5 * (P + P.T))
    return _chol_solve(L, np.eye(P.shape[0]))


__all__ = [
    "NAME_PROBABILITY",
    "Change",
    "CheckRun",
    "ChangeFamily",
    "ChangeModel",
    "CheckSettings",
    "CheckStatus",
    "Decision",
    "FamilyKind",
    "change_model",
    "check_status",
    "information_gains",
]
