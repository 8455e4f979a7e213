"""Is an identified model physically believable?  Judged on what the robot does, not on
coefficients.

Coefficients depend on the gauge (how the fit splits error between base, tool and the joints'
constant terms) and on the Chebyshev ranges: a 568 mm coefficient can describe a robot that
is 1 mm off.  What cannot depend on either is the **TCP correction**: the model's target
pose against the nominal robot after the best rigid registration of base and tool
(:attr:`~quickhealth.identify.fit.FittedModel.registration`), over the joint ranges the model
was identified on.  A real robot, even a worn or crashed one, is within centimetres and
degrees of its nominal kinematics once base and tool are registered; beyond the limits below
the model describes something else (wrong units, the wrong robot, a broken instrument frame).

Every reader of a model (``predict``, ``diagnose``, ``compare``, ``compensate``, ``export``)
and the fit itself apply :func:`check_plausible`, so ``identify fit`` never writes a model
its readers refuse.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .effects import reference_conditions
from .errors import InputError, QuickhealthError
from .fit import FittedModel
from .measurements import Measurements

F = NDArray[np.float64]

#: Largest believable TCP position correction (m) over the identified range.
MAX_TCP_CORRECTION = 0.05
#: Largest believable TCP orientation correction (rad) over the identified range.
MAX_ROT_CORRECTION = 0.05
#: Joint commands the correction is sampled at (uniform over the identified ranges).
EXTENT_SAMPLES = 1000
#: Largest believable residual of a fitted model: position RMS (m, 3-D) and orientation RMS
#: (rad).  What a model of a real robot leaves is its unmodelled error and the instrument's
#: noise: tenths of a millimetre on an arm, 2 mm on a cable-driven one.  Beyond these the
#: joints and the measured poses do not belong together.
MAX_RESIDUAL_POS = 0.01
MAX_RESIDUAL_ROT = np.radians(2.0)


class NumericalError(QuickhealthError):
    """The computation failed (no convergence, numbers that are not finite).  Exit status 3."""

    exit_status = 3


@dataclass(frozen=True)
class CorrectionExtent:
    """Largest TCP correction of a model over its identified joint ranges."""

    max_pos: float  # m
    max_rot: float  # rad
    q_pos: F  # (nj,) rad, where the position correction is largest
    q_rot: F  # (nj,) rad

    def describe(self) -> str:
        """``"4.1 mm, 3.2 mrad"``."""
        return f"{self.max_pos * 1e3:.3g} mm, {self.max_rot * 1e3:.3g} mrad"


def correction_extent(fitted: FittedModel, n_samples: int = EXTENT_SAMPLES) -> CorrectionExtent:
    """The TCP correction (model against registered nominal) over the identified ranges."""
    rng = np.random.default_rng(1)
    spec = fitted.spec
    q = rng.uniform(spec.q_lo, spec.q_hi, (n_samples, spec.n_joints))
    needs = {col for e in fitted.effects for col in e.requires()}
    kw: dict[str, F | None] = {
        "approach": np.ones_like(q),
        **reference_conditions(needs, fitted.robot, q, fitted.reference_time),
    }
    with np.errstate(all="ignore"):
        dp = np.linalg.norm(fitted.tcp_error_vector(q, **kw), axis=1)
        dr = np.linalg.norm(fitted.tcp_rotation_error(q, **kw), axis=1)
    if not (np.all(np.isfinite(dp)) and np.all(np.isfinite(dr))):
        return CorrectionExtent(np.inf, np.inf, q[0], q[0])
    return CorrectionExtent(
        float(dp.max()), float(dr.max()), q[int(np.argmax(dp))], q[int(np.argmax(dr))]
    )


def check_plausible(fitted: FittedModel, name: str = "model") -> CorrectionExtent:
    """Refuse a model whose TCP correction is beyond any real robot (one line).

    The orientation is judged only for a model fitted to full-pose data: position-only data
    leave it unobserved (a wrist tilt with a short lever moves the point little).

    Raises
    ------
    InputError
        The correction over the identified ranges exceeds :data:`MAX_TCP_CORRECTION` or
        (full-pose models) :data:`MAX_ROT_CORRECTION`, or is not finite.
    """
    ext = correction_extent(fitted)
    if not np.isfinite(ext.max_pos):
        raise InputError(f"{name}: the model's TCP correction is not a finite number")
    checks = [(ext.max_pos, MAX_TCP_CORRECTION, ext.q_pos, "mm", "position")]
    if fitted.has_orientation:  # position-only data do not observe the orientation it models
        checks.append((ext.max_rot, MAX_ROT_CORRECTION, ext.q_rot, "mrad", "orientation"))
    for value, limit, q, unit, what in checks:
        if value > limit:
            qd = ", ".join(f"{v:.0f}" for v in np.degrees(q))
            raise InputError(
                f"{name}: its TCP {what} correction reaches {value * 1e3:.4g} {unit} (limit "
                f"{limit * 1e3:.0f} {unit}) at joints ({qd}) deg within the identified ranges, "
                "beyond any real robot once base and tool are registered"
            )
    return ext


def check_residuals(fitted: FittedModel, name: str = "the data") -> None:
    """Refuse a fit whose residuals no robot model leaves (one line).

    Raises
    ------
    InputError
        Position RMS above :data:`MAX_RESIDUAL_POS` or orientation RMS above
        :data:`MAX_RESIDUAL_ROT`: columns swapped, another robot's file, wrong units.
    """
    rot = fitted.rms_rot
    if fitted.rms_pos > MAX_RESIDUAL_POS or (rot is not None and rot > MAX_RESIDUAL_ROT):
        what = f"position RMS {fitted.rms_pos * 1e3:.4g} mm" + (
            f", orientation RMS {np.degrees(rot):.4g} deg" if rot is not None else ""
        )
        raise InputError(
            f"{name}: the model leaves residuals no robot's model leaves ({what}; limits "
            f"{MAX_RESIDUAL_POS * 1e3:.0f} mm, {np.degrees(MAX_RESIDUAL_ROT):.0f} deg): the "
            "joint readings and the measured poses do not belong together (columns swapped, "
            "another robot's file, wrong units or robot description)"
        )


#: New data may leave this many times the model's own residual RMS, and this much (m) more,
#: before the model is taken not to describe them (another robot or set-up).
FOREIGN_FACTOR = 10.0
FOREIGN_MARGIN = 0.002


def check_describes(fitted: FittedModel, meas: Measurements, name: str = "the data") -> float:
    """Refuse data the model does not describe (one line); returns their position RMS (m).

    A diagnosis compares residuals with the model's structure; on another robot's or another
    set-up's data (residuals of centimetres against a model that left tenths of a
    millimetre) every candidate would be "significant" or none: neither is an answer.
    """
    T = fitted.predict(meas.q, **meas.conditions())
    res = meas.pos - T[:, :3, 3]
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1))))
    limit = max(FOREIGN_FACTOR * fitted.rms_pos, fitted.rms_pos + FOREIGN_MARGIN)
    if not rms <= limit:
        raise InputError(
            f"{name}: the model does not describe this data: position RMS {rms * 1e3:.4g} mm "
            f"against the {fitted.rms_pos * 1e3:.4g} mm it was fitted to (limit "
            f"{limit * 1e3:.3g} mm): another robot or set-up, or a robot changed beyond its "
            "model; fit this data first (identify fit)"
        )
    return rms


def weakest_directions(fitted: FittedModel, k: int = 3) -> list[str]:
    """The ``k`` parameters the data determine least, relative to their prior (label and σ)."""
    from .select import _prior_sigmas

    fixed = set(fitted.unidentifiable) | set(fitted.held)
    ratio = fitted.sigma / np.maximum(_prior_sigmas(fitted), 1e-300)
    order = np.argsort(-ratio)
    out = []
    for i in order:
        lb = fitted.labels[i]
        if lb in fixed:
            continue
        parts = lb.split(".")
        if len(parts) == 3 and parts[1] in ("dx", "dy", "dz", "ex", "ey", "ez"):
            unit = "mrad" if parts[1].startswith("e") else "mm"
            out.append(f"{lb} (sigma {fitted.sigma[i] * 1e3:.3g} {unit})")
        else:  # an effect's parameter, in its own SI unit
            out.append(f"{lb} (sigma {fitted.sigma[i]:.3g})")
        if len(out) == k:
            break
    return out
