"""What the identified model says about the robot (METHOD.md Sec. 5, paper Figs. 7–8).

- :func:`workspace_error`: TCP error evaluated from the model over the whole joint range the
  model covers (not only at measured poses): mean, standard deviation, maximum, histogram.
- :func:`joint_curves`: each joint's six error motions over its range with confidence bands
  from the estimate's covariance.
- :func:`predict_commands`: predicted TCP error of new joint commands (a robot program before
  it runs), with its standard uncertainty and flags above a threshold or outside the range the
  model was identified on.

Effects that depend on conditions are evaluated at stated reference conditions
(:class:`Conditions`, :func:`reference_conditions`): ``thermal`` at 20 °C (the temperature its
link lengths refer to), ``drift`` at the time of the last pose the model was fitted to (where
the instrument-to-robot relation is at the end of the run; a drift moves the base in the
instrument, it is no TCP error of the robot).  Every result names the conditions it used.

The bands propagate the covariance of the estimate (sampling error).  They leave out model
error (effects the model does not have) and coefficients the data could not identify (held
at zero; see ``FittedModel.unidentifiable``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .distributions import chi2_ppf, norm_ppf
from .effects import T_REF_C, Perturbation
from .effects import reference_conditions as effect_reference
from .errormodel import MOTIONS, chebyshev_basis, chebyshev_u
from .fit import REGISTRATION_SAMPLES, FittedModel, linearised
from .linearize import forward, motion_jacobian
from .measurements import Measurements
from .robot import RobotModel
from .transforms import skew

F = NDArray[np.float64]


#: How the joint torques are taken at reference conditions (:attr:`Conditions.joint_torque`).
TORQUE_GRAVITY = "holding the robot model's masses against gravity"
TORQUE_NONE = "zero (the robot model has no masses: the arm counts as unloaded)"


@dataclass(frozen=True)
class Conditions:
    """The conditions a model with condition-dependent effects is evaluated at.

    ``temp_c`` (°C) is set when an effect needs ``temp``, ``time_s`` (s) when one needs
    ``time``, ``joint_temp_c`` (°C, every joint) when one needs ``joint_temp`` and
    ``joint_torque`` (how the torques are taken: :data:`TORQUE_GRAVITY` or
    :data:`TORQUE_NONE`) when one needs ``joint_torque``; ``None`` otherwise (the model
    does not depend on it).
    """

    temp_c: float | None = None
    time_s: float | None = None
    time_note: str = ""
    joint_temp_c: float | None = None
    joint_torque: str | None = None

    @property
    def channels(self) -> list[str]:
        """The channels these conditions set (``temp``, ``time``, ``joint_temp``, …)."""
        given = (
            ("temp", self.temp_c),
            ("time", self.time_s),
            ("joint_temp", self.joint_temp_c),
            ("joint_torque", self.joint_torque),
        )
        return [c for c, v in given if v is not None]

    def arrays(self, q: ArrayLike, robot: RobotModel) -> dict[str, F | None]:
        """The conditions of the commands ``q`` (n, nj) as ``FittedModel.predict`` keywords."""
        q = np.atleast_2d(np.asarray(q, float))
        n = q.shape[0]
        return {
            "temp": None if self.temp_c is None else np.full(n, self.temp_c),
            "time": None if self.time_s is None else np.full(n, self.time_s),
            "joint_temp": None
            if self.joint_temp_c is None
            else np.full(q.shape, self.joint_temp_c),
            "joint_torque": (
                None
                if self.joint_torque is None
                else effect_reference({"joint_torque"}, robot, q, None)["joint_torque"]
            ),
        }

    def describe(self) -> str:
        """One phrase, e.g. ``at 20.0 °C, time 900.0 s (the run's last pose)``; '' if none."""
        parts = []
        if self.temp_c is not None:
            parts.append(f"{self.temp_c:.1f} °C")
        if self.time_s is not None:
            parts.append(
                f"time {self.time_s:.1f} s" + (f" ({self.time_note})" if self.time_note else "")
            )
        if self.joint_temp_c is not None:
            parts.append(f"every joint at {self.joint_temp_c:.1f} °C")
        if self.joint_torque is not None:
            parts.append(f"joint torques {self.joint_torque}")
        return "at " + ", ".join(parts) if parts else ""

    def as_dict(self) -> dict[str, object]:
        """For report.json: ``temp_c``, ``time_s`` (null when the model does not use them),
        and ``joint_temp_c``, ``joint_torque`` when it does."""
        out: dict[str, object] = {"temp_c": self.temp_c, "time_s": self.time_s}
        if self.joint_temp_c is not None:
            out["joint_temp_c"] = self.joint_temp_c
        if self.joint_torque is not None:
            out["joint_torque"] = self.joint_torque
        return {**out, "text": self.describe()}


def reference_conditions(fitted: FittedModel) -> Conditions:
    """The stated reference conditions of ``fitted`` (the values of
    :func:`~quickhealth.identify.effects.reference_conditions`): 20 °C for ``thermal`` and
    every joint's temperature, the time of the last fitted pose for ``drift`` (0 s if the
    model does not know it), the torques that hold the model's masses for a torque effect."""
    needs = {col for e in fitted.effects for col in e.requires()}
    temp = T_REF_C if "temp" in needs else None
    time = note = None
    if "time" in needs:
        if fitted.reference_time is not None:
            time, note = float(fitted.reference_time), "the run's last pose"
        else:
            time, note = 0.0, "the time origin; the model does not know its run's times"
    torque = None
    if "joint_torque" in needs:
        r = fitted.robot
        torque = TORQUE_GRAVITY if r.masses is not None and r.coms is not None else TORQUE_NONE
    return Conditions(temp, time, note or "", T_REF_C if "joint_temp" in needs else None, torque)


@dataclass(frozen=True, eq=False)
class WorkspaceError:
    """Distribution of the model's TCP position error over uniformly sampled joint commands (m)."""

    n_samples: int
    mean: float
    std: float
    max: float
    p95: float
    q_worst: F  # (nj,) rad, the sampled command with the largest error
    hist_counts: NDArray[np.int64]
    hist_edges: F  # m
    conditions: Conditions = Conditions()

    def as_dict(self) -> dict[str, object]:
        """Numbers for report.json (mm)."""
        return {
            "conditions": self.conditions.as_dict(),
            "n_samples": self.n_samples,
            "mean_mm": self.mean * 1e3,
            "std_mm": self.std * 1e3,
            "max_mm": self.max * 1e3,
            "p95_mm": self.p95 * 1e3,
            "q_worst_deg": np.degrees(self.q_worst).tolist(),
            "histogram": {
                "counts": self.hist_counts.tolist(),
                "edges_mm": (self.hist_edges * 1e3).tolist(),
            },
        }


@dataclass(frozen=True, eq=False)
class JointCurves:
    """The six error motions of one joint over its range, with confidence bands."""

    joint: int  # 1-based
    theta: F  # (k,) rad
    values: F  # (6, k): δx δy δz (m), εx εy εz (rad)
    sigma: F  # (6, k) standard uncertainty
    level: float  # e.g. 0.95
    half_width: F  # (6, k) simultaneous band half-width at ``level`` (whole curve)
    pointwise_half_width: F  # (6, k) pointwise band half-width at ``level``

    def as_dict(self) -> dict[str, object]:
        """Numbers for report.json (deg, mm, mrad)."""
        scale = np.array([1e3, 1e3, 1e3, 1e3, 1e3, 1e3])[:, None]
        return {
            "joint": self.joint,
            "theta_deg": np.degrees(self.theta).tolist(),
            "level": self.level,
            "band": "simultaneous over the range (half_width); pointwise_half_width per angle",
            "units": {"dx": "mm", "dy": "mm", "dz": "mm", "ex": "mrad", "ey": "mrad", "ez": "mrad"},
            "motions": {
                m: {
                    "value": (self.values[i] * scale[i]).tolist(),
                    "half_width": (self.half_width[i] * scale[i]).tolist(),
                    "pointwise_half_width": (self.pointwise_half_width[i] * scale[i]).tolist(),
                }
                for i, m in enumerate(MOTIONS)
            },
        }


@dataclass(frozen=True, eq=False)
class CommandPrediction:
    """Predicted TCP error of joint commands."""

    T_instr_target: F  # (n, 4, 4)
    err: F  # (n,) m
    err_vec: F  # (n, 3) m, instrument frame
    err_sigma: F  # (n,) m, standard uncertainty of err from the covariance
    over_threshold: NDArray[np.bool_]  # (n,)
    extrapolated: NDArray[np.bool_]  # (n,) some joint outside the identified range
    threshold: float | None
    assumed: Conditions = Conditions()  # conditions assumed where the input had no column


def workspace_commands(fitted: FittedModel, n_samples: int = 5000, seed: int = 0) -> F:
    """The joint commands (rad, (n, nj)) the workspace figures are taken over: uniform over
    the model's identified ranges, from a fixed seed."""
    rng = np.random.default_rng(seed)
    spec = fitted.spec
    return rng.uniform(spec.q_lo, spec.q_hi, (n_samples, spec.n_joints))


@dataclass(frozen=True, eq=False)
class WorkspaceMap:
    """Where in the workspace the model's TCP error is: each sampled command's TCP position in
    the robot base frame (m; the nominal kinematics with the registered tool) and its error
    (m), the same samples as :func:`workspace_error`'s."""

    xyz_base: F  # (n, 3) m
    err: F  # (n,) m
    q: F  # (n, nj) rad

    @property
    def worst(self) -> int:
        """Index of the sample with the largest error."""
        return int(np.argmax(self.err))


def workspace_map(
    fitted: FittedModel,
    n_samples: int = 5000,
    seed: int = 0,
    conditions: Conditions | None = None,
) -> WorkspaceMap:
    """The TCP error over the workspace as a map (:class:`WorkspaceMap`), at ``conditions``
    (default :func:`reference_conditions`)."""
    cond = reference_conditions(fitted) if conditions is None else conditions
    q = workspace_commands(fitted, n_samples, seed)
    err = fitted.tcp_error(q, approach=np.ones_like(q), **cond.arrays(q, fitted.robot))
    _, T_ft = fitted.registration
    xyz = (fitted.robot.fk(q).reshape(-1, 4, 4) @ T_ft)[:, :3, 3]
    return WorkspaceMap(xyz, np.asarray(err, float), q)


def workspace_error(
    fitted: FittedModel,
    n_samples: int = 5000,
    seed: int = 0,
    bins: int = 40,
    conditions: Conditions | None = None,
) -> WorkspaceError:
    """TCP error from the model at ``n_samples`` joint commands uniform over the model's ranges,
    at ``conditions`` (default :func:`reference_conditions`)."""
    cond = reference_conditions(fitted) if conditions is None else conditions
    q = workspace_commands(fitted, n_samples, seed)
    err = fitted.tcp_error(q, approach=np.ones_like(q), **cond.arrays(q, fitted.robot))
    return error_distribution(q, np.asarray(err, float), cond, bins)


def error_distribution(q: F, err: F, conditions: Conditions, bins: int = 40) -> WorkspaceError:
    """The :class:`WorkspaceError` of TCP errors ``err`` (m) at commands ``q`` (a
    :class:`WorkspaceMap`'s: the figures and the map from one evaluation)."""
    n_samples = len(err)
    cond = conditions
    counts, edges = np.histogram(err, bins=bins, range=(0.0, float(err.max()) * 1.0001 + 1e-12))
    return WorkspaceError(
        n_samples=n_samples,
        mean=float(err.mean()),
        std=float(err.std()),
        max=float(err.max()),
        p95=float(np.percentile(err, 95)),
        q_worst=q[int(np.argmax(err))],
        hist_counts=counts,
        hist_edges=edges,
        conditions=cond,
    )


def figures_over(fitted: FittedModel, q: F) -> dict[str, float]:
    """Mean, standard deviation and maximum TCP error (m) at the joint commands ``q`` (n, nj):
    a fixed evaluation set (a baseline's measured poses), the nominal robot registered to
    the model over the same commands, at the reference conditions.

    Where two runs measured different poses, their workspace figures (uniform over each run's
    own identified ranges) differ by what each model extrapolates: on splits of the shared
    UR10 series the mean moved by up to 0.08 mm and the maximum by up to 0.4 mm; at the
    baseline's own poses by at most 0.02 mm and 0.11 mm (docs/monitoring.md)."""
    q = np.atleast_2d(np.asarray(q, float))
    cond = reference_conditions(fitted)
    T = fitted.robot_pose(q, approach=np.zeros_like(q), **cond.arrays(q, fitted.robot))
    T_ib, T_ft = fitted.registration_over(q)
    nom = T_ib @ fitted.robot.fk(q).reshape(-1, 4, 4) @ T_ft
    err = np.linalg.norm(T[:, :3, 3] - nom[:, :3, 3], axis=1)
    return {"mean": float(err.mean()), "std": float(err.std()), "max": float(err.max())}


def joint_curves(
    fitted: FittedModel, joint: int, n_points: int = 121, level: float = 0.95
) -> JointCurves:
    """Error motions of ``joint`` (1-based) over its identified range, with bands at ``level``.

    ``half_width`` is a simultaneous (Scheffé) band: with probability ``level`` the whole
    true curve lies inside it over the entire range (``sqrt(χ²_k(level)) · σ(θ)`` for a
    series with k estimated coefficients).  ``pointwise_half_width`` holds at each angle
    separately (``z · σ(θ)``).  Coefficients the data cannot identify are held at zero and
    not in the band (the curve is then defined up to that gauge, e.g. a constant εz of joint
    1 is a base rotation).
    """
    spec = fitted.spec
    if not 1 <= joint <= spec.n_joints:
        raise ValueError(f"joint must be 1..{spec.n_joints}, got {joint}")
    j = joint - 1
    theta = np.linspace(spec.q_lo[j], spec.q_hi[j], n_points)
    u = chebyshev_u(theta, spec.q_lo[j], spec.q_hi[j])
    idx = spec.index()
    values = np.zeros((6, n_points))
    sigma = np.zeros((6, n_points))
    k_free = np.ones(6)
    for m in range(6):
        sel = np.flatnonzero((idx[:, 0] == joint) & (idx[:, 1] == m))
        if sel.size == 0:
            continue
        B = chebyshev_basis(u, int(idx[sel, 2].max()))[:, idx[sel, 2]]  # (k, nc)
        values[m] = B @ fitted.coeffs[sel]
        C = fitted.cov[np.ix_(sel, sel)]
        sigma[m] = np.sqrt(np.clip(np.einsum("ki,ij,kj->k", B, C, B), 0.0, None))
        k_free[m] = max(int(np.sum(np.diag(C) > 0)), 1)
    z = norm_ppf(0.5 + level / 2)
    zs = np.sqrt([chi2_ppf(level, k) for k in k_free])[:, None]
    return JointCurves(joint, theta, values, sigma, level, zs * sigma, z * sigma)


def all_joint_curves(
    fitted: FittedModel, n_points: int = 121, level: float = 0.95
) -> list[JointCurves]:
    """:func:`joint_curves` of every joint."""
    return [joint_curves(fitted, j, n_points, level) for j in range(1, fitted.spec.n_joints + 1)]


def predict_commands(
    fitted: FittedModel,
    q: ArrayLike,
    threshold: float | None = None,
    **conditions: ArrayLike | None,
) -> CommandPrediction:
    """Predicted pose and TCP error for joint commands ``q`` (rad, (n, nj)), in program order.

    ``threshold`` (m) flags commands whose predicted error exceeds it.  Commands with a joint
    outside the range the model was identified on are flagged ``extrapolated``: the Chebyshev
    series are not trusted there.  ``conditions``: ``time=``, ``temp=``, ``joint_temp=``,
    ``joint_torque=`` of the commands (``**meas.conditions()``); where the model needs one
    that is not given, the reference conditions are used and returned in ``assumed``.
    """
    q = np.atleast_2d(np.asarray(q, float))
    ref = reference_conditions(fitted)
    have = {c for c, v in conditions.items() if v is not None}
    assumed = Conditions(
        ref.temp_c if "temp" not in have else None,
        ref.time_s if "time" not in have else None,
        ref.time_note if "time" not in have else "",
        ref.joint_temp_c if "joint_temp" not in have else None,
        ref.joint_torque if "joint_torque" not in have else None,
    )
    fill = assumed.arrays(q, fitted.robot)
    given = {c: conditions.get(c) if c in have else fill[c] for c in fill}
    if fitted.effects:
        T = fitted.predict(q, **given)
        ev = fitted.tcp_error_vector(q, **given)
        Jt = _joint_coeff_position_jacobian(fitted, q)  # (n, 3, P)
    else:  # one forward pass serves the pose, the error and the Jacobian (no perturbation)
        fw = forward(
            fitted.robot,
            fitted.spec,
            fitted.coeffs,
            fitted.T_instr_base0,
            fitted.T_flange_target0,
            q,
            Perturbation(),
        )
        T = fw[0]
        ev = T[:, :3, 3] - fitted.nominal_pose(q)[:, :3, 3]
        Jt = _joint_coeff_position_jacobian(fitted, q, fw)
    err = np.linalg.norm(ev, axis=1)
    sel = _joint_coeff_index(fitted)
    C = fitted.cov[np.ix_(sel, sel)]
    Jt = Jt - np.einsum("nir,rp->nip", _registration_columns(fitted, q), _registration_gain(fitted))
    dirn = ev / np.maximum(err, 1e-15)[:, None]
    g = np.einsum("ni,nip->np", dirn, Jt)
    var = np.einsum("np,pq,nq->n", g, C, g)
    spec = fitted.spec
    extrap = np.any((q < spec.q_lo - 1e-9) | (q > spec.q_hi + 1e-9), axis=1)
    over = err > threshold if threshold is not None else np.zeros(len(q), bool)
    return CommandPrediction(
        T, err, ev, np.sqrt(np.clip(var, 0, None)), over, extrap, threshold, assumed
    )


def prediction_band(fitted: FittedModel, meas: Measurements, level: float = 0.95) -> F:
    """Radius (m) within which the model expects each row's *measured* position, shape (n,).

    The predicted position's covariance from the estimate's covariance (every parameter,
    through the model Jacobian at the row) plus the measurement's own covariance under the
    model's noise (the row's stated uncertainty or the instrument default, the encoders
    through the loop, and the scatter the fit estimated beyond the stated uncertainty:
    ``InstrumentNoise.excess_pos``), the measurement part widened at 95 % by
    ``InstrumentNoise.band_factor`` (the residuals' tails).  The radius of a 3-D Gaussian with covariance ``C`` at
    probability ``level`` is taken by Satterthwaite's approximation: ``|x|² ≈ g χ²_h`` with
    ``g = Σλ²/Σλ`` and ``h = (Σλ)²/Σλ²`` over the eigenvalues ``λ`` of ``C`` (exact for an
    isotropic ``C``; within a few per cent otherwise).
    """
    lin = linearised(fitted, meas)
    n, d = meas.n_poses, lin.d
    L = np.linalg.inv(lin.W)  # Σx^{1/2}
    J = (L @ lin.J.reshape(n, d, -1))[:, :3]  # (n, 3, P) raw model Jacobian, position rows
    tails = fitted.noise.band_factor**2 if level == 0.95 else 1.0
    C = np.einsum("nip,pq,njq->nij", J, fitted.cov, J) + lin.cov[:, :3, :3] * tails
    lam = np.clip(np.linalg.eigvalsh(C), 0.0, None)
    s1, s2 = lam.sum(1), (lam * lam).sum(1)
    g = s2 / np.maximum(s1, 1e-300)
    h = np.clip(s1 * s1 / np.maximum(s2, 1e-300), 1.0, 3.0)
    grid = np.linspace(1.0, 3.0, 81)
    q = np.interp(h, grid, [chi2_ppf(level, x) for x in grid])
    return np.sqrt(g * q)


def _registration_columns(fitted: FittedModel, q: F) -> F:
    """∂(registered nominal position)/∂(base rotation, base translation, tool point), (n, 3, 9)."""
    T_rb, T_rt = fitted.registration
    T_bf = fitted.robot.fk(q).reshape(-1, 4, 4)
    y = (T_bf[:, :3, :3] @ T_rt[:3, 3] + T_bf[:, :3, 3]) @ T_rb[:3, :3].T  # R_B y, base part
    return np.concatenate(
        [-skew(y), np.broadcast_to(np.eye(3), (len(q), 3, 3)), T_rb[:3, :3] @ T_bf[:, :3, :3]],
        axis=2,
    )


def _registration_gain(fitted: FittedModel) -> F:
    """How the registration follows the joint coefficients, ``(GᵀG)⁻¹ Gᵀ J`` over its sample
    (9, n_joint_coeffs): a coefficient change the registration can absorb is no TCP error, so
    the registered error's uncertainty leaves it out."""
    rng = np.random.default_rng(0)  # the registration's own sample (FittedModel.registration)
    spec = fitted.spec
    q = rng.uniform(spec.q_lo, spec.q_hi, (REGISTRATION_SAMPLES, spec.n_joints))
    G = _registration_columns(fitted, q).reshape(-1, 9)
    J = _joint_coeff_position_jacobian(fitted, q).reshape(len(G), -1)
    return np.linalg.lstsq(G, J, rcond=None)[0]


def _joint_coeff_index(fitted: FittedModel) -> NDArray[np.int64]:
    idx = fitted.spec.index()
    return np.flatnonzero((idx[:, 0] >= 1) & (idx[:, 0] <= fitted.spec.n_joints))


def _joint_coeff_position_jacobian(fitted: FittedModel, q: F, fw: tuple | None = None) -> F:
    """∂(target position)/∂(joint Chebyshev coefficients), shape (n, 3, n_joint_coeffs).

    ``fw``: the unperturbed ``forward`` result for ``q`` when the caller has it already.
    """
    spec = fitted.spec
    T, A, mot = fw or forward(
        fitted.robot,
        spec,
        fitted.coeffs,
        fitted.T_instr_base0,
        fitted.T_flange_target0,
        q,
        Perturbation(),
    )
    assert A is not None and mot is not None
    Jm = motion_jacobian(T, A, mot, None)[:, :3]  # (n, 3, nf, 6)
    idx = spec.index()[_joint_coeff_index(fitted)]
    if idx.size == 0:
        return np.zeros((q.shape[0], 3, 0))
    u = chebyshev_u(q, spec.q_lo, spec.q_hi)
    B = chebyshev_basis(u, int(idx[:, 2].max()))  # (n, nj, K)
    basis = B[:, idx[:, 0] - 1, idx[:, 2]]
    return Jm[:, :, idx[:, 0], idx[:, 1]] * basis[:, None, :]
