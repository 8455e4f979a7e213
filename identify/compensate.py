"""Acting on an identified model: corrected kinematics exports and program compensation.

Three uses of the fitted error model, each a pure function:

1. ``corrected_robot``   the geometric part (each joint's error motions averaged over its
   range, a constant ``E_i``) folded into the robot's constant link transforms, and
   ``urdf_text`` that writes any :class:`RobotModel` as a URDF (joint origins);
2. ``dh_deltas``         UR-style kinematics parameters: ``delta_theta, delta_a, delta_d,
   delta_alpha`` per joint on the manufacturer's DH table, fitted to the corrected kinematics,
   with what DH cannot express reported as a residual; ``ur_calibration_text`` formats them;
3. ``compensate_joints`` rewrites joint targets so that the *modelled* TCP lands on the
   nominal target (Newton iterations on the model), with the remaining predicted error per
   target; ``urscript_joint_targets`` / ``urscript_replace_targets`` apply it to a URScript
   program's ``movej([...])``-style joint lists.

What is left out: base and tool corrections (``E0``, ``Etool``) belong to the instrument set-up
and the measurement target, not to the robot; physical effects (compliance, backlash …)
are not part of the geometric export.  ``compensate_joints`` uses the full Chebyshev model
(all orders), so higher-order joint errors are compensated too.

SYNOPSIS::

    robot_c = corrected_robot(robot, spec, coeffs)
    open("corrected.urdf", "w").write(urdf_text(robot_c))
    comp = compensate_joints(robot, spec, coeffs, q_program)
    comp.q, comp.residual_pos      # new targets (rad), remaining predicted error (m)
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from xml.sax.saxutils import escape as xml_escape

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from .errormodel import ErrorModelSpec, joint_error_motions
from .robot import RobotModel, chain, from_dh
from .transforms import R_to_rpy, inv_T, log_so3, small_error_transform
from .urscript import joint_targets, replace_targets

F = NDArray[np.float64]


# ----------------------------------------------------------------- geometric part, URDF


def geometric_part(spec: ErrorModelSpec, coeffs: ArrayLike, n_grid: int = 201) -> F:
    """Each joint's six error motions averaged over its range, shape (nj, 6), m / rad."""
    q = np.linspace(spec.q_lo, spec.q_hi, n_grid)
    return joint_error_motions(spec, np.asarray(coeffs, float), q).mean(axis=0)


def corrected_robot(robot: RobotModel, spec: ErrorModelSpec, coeffs: ArrayLike) -> RobotModel:
    """The robot with its identified constant joint errors folded into the link transforms.

    ``E_i`` sits right after ``Rz(θ_i)``, so ``Rz(θ_i) · E_i · C_i = Rz(θ_i) · C_i'`` with
    ``C_i' = E_i · C_i``: exact for the constant part of every motion, εz included (a joint zero
    offset).
    """
    g = geometric_part(spec, coeffs)
    E = small_error_transform(g[:, :3], g[:, 3:])  # (nj, 4, 4)
    links = robot.links.copy()
    links[1:] = E @ robot.links[1:]
    return replace(
        robot, name=f"{robot.name}_corrected", links=links, convention="generic", dh=None
    )


def _attr(text: str) -> str:
    """``text`` escaped for a double-quoted XML attribute (&, <, >, quotes); tab, newline and
    CR as character references; other control characters (not allowed in XML 1.0) as ``_``."""
    out = xml_escape(str(text), {'"': "&quot;", "'": "&apos;"})
    return "".join(
        c if c >= " " and c != "\x7f" else (f"&#{ord(c)};" if c in "\t\n\r" else "_") for c in out
    )


def _fmt(v: ArrayLike) -> str:
    return " ".join(f"{x:.9g}" for x in np.asarray(v, float))


def urdf_text(robot: RobotModel, *, name: str | None = None) -> str:
    """A URDF of the robot's kinematics: revolute joints about z, origins from the link transforms.

    Joint i's origin is ``C_{i-1} · Rz(o_i)`` (the zero offset folded in); a fixed joint to
    ``flange`` carries ``C_n``.  Link masses and centres of mass are written when known.
    URDF ``rpy`` is fixed-axis x-y-z: ``R = Rz(y) · Ry(p) · Rx(r)``.
    """
    nj = robot.n_joints
    names = list(robot.joint_names) or [f"j{i + 1}" for i in range(nj)]
    lines = [
        '<?xml version="1.0"?>',
        f'<robot name="{_attr(name or robot.name)}">',
        '  <link name="base_link"/>',
    ]
    for i in range(nj):
        origin = robot.links[i].copy()
        c, s = np.cos(robot.q_offset[i]), np.sin(robot.q_offset[i])
        Rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        origin = origin @ Rz
        parent = "base_link" if i == 0 else f"link{i}"
        child = f"link{i + 1}"
        if robot.masses is not None and robot.coms is not None:
            # CoM is given in the frame after Rz(θ_i)·C_i; URDF link frames sit before C_i.
            com = robot.links[i + 1] @ np.append(robot.coms[i], 1.0)
            m = float(robot.masses[i])
            lines.append(
                f'  <link name="{child}"><inertial><origin xyz="{_fmt(com[:3])}" rpy="0 0 0"/>'
                f'<mass value="{m:.6g}"/><inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" '
                'izz="1e-4"/></inertial></link>'
            )
        else:
            lines.append(f'  <link name="{child}"/>')
        lines += [
            f'  <joint name="{_attr(names[i])}" type="revolute">',
            f'    <parent link="{parent}"/><child link="{child}"/>',
            f'    <origin xyz="{_fmt(origin[:3, 3])}" rpy="{_fmt(R_to_rpy(origin[:3, :3]))}"/>',
            '    <axis xyz="0 0 1"/>',
            f'    <limit lower="{robot.q_min[i]:.9g}" upper="{robot.q_max[i]:.9g}" '
            'effort="150" velocity="3.15"/>',
            "  </joint>",
        ]
    last = robot.links[nj]
    lines += [
        '  <link name="flange"/>',
        '  <joint name="flange_fixed" type="fixed">',
        f'    <parent link="link{nj}"/><child link="flange"/>',
        f'    <origin xyz="{_fmt(last[:3, 3])}" rpy="{_fmt(R_to_rpy(last[:3, :3]))}"/>',
        "  </joint>",
        "</robot>",
        "",
    ]
    return "\n".join(lines)


# ------------------------------------------------------------------------- DH deltas


@dataclass(frozen=True)
class DhCalibration:
    """UR-style kinematics deltas on the nominal standard-DH table (m, rad), per joint.

    ``residual_pos_rms`` / ``residual_rot_rms`` (m, rad): how far the DH-corrected flange
    stays from the fully corrected kinematics over the sampled joint space — what four DH
    numbers per joint cannot express (e.g. a tilt of joint 1 against the base).
    """

    delta_theta: F
    delta_a: F
    delta_d: F
    delta_alpha: F
    residual_pos_rms: float
    residual_rot_rms: float
    nominal_residual_pos_rms: float  # nominal DH against the corrected kinematics, for scale

    def robot(self, nominal: RobotModel) -> RobotModel:
        """The nominal robot with these deltas applied."""
        return _dh_robot(
            nominal,
            np.concatenate([self.delta_theta, self.delta_a, self.delta_d, self.delta_alpha]),
        )


def _dh_robot(nominal: RobotModel, x: F) -> RobotModel:
    dh = nominal.dh
    assert dh is not None
    n = nominal.n_joints
    return from_dh(
        nominal.name,
        a=np.asarray(dh["a"]) + x[n : 2 * n],
        d=np.asarray(dh["d"]) + x[2 * n : 3 * n],
        alpha=np.asarray(dh["alpha"]) + x[3 * n :],
        theta_offset=np.asarray(dh["theta_offset"]) + x[:n],
        q_min=nominal.q_min,
        q_max=nominal.q_max,
        joint_names=nominal.joint_names,
    )


def _pose_diff(A: F, B: F) -> F:
    """Position (m) and rotation-vector (rad) difference of pose stacks, shape (n, 6)."""
    D = inv_T(B) @ A
    return np.concatenate([A[:, :3, 3] - B[:, :3, 3], log_so3(D[:, :3, :3])], axis=1)


def dh_deltas(
    robot: RobotModel,
    spec: ErrorModelSpec,
    coeffs: ArrayLike,
    *,
    n_samples: int = 60,
    seed: int = 0,
    rot_weight_m: float = 0.5,
    max_nfev: int = 2000,
    ridge: float = 1e-3,
) -> DhCalibration:
    """Fit UR-style DH deltas to the corrected kinematics (least squares over joint space).

    Parameters
    ----------
    robot : RobotModel
        Must come from a standard DH table (``robot.dh``, ``convention == "dh"``).
    spec, coeffs : the identified error model
    n_samples : int
        Random joint configurations within the model's joint ranges.
    rot_weight_m : float, m
        Lever arm that converts rotation residuals into length in the fit.
    max_nfev : int
        Limit of model evaluations of the least-squares fit.
    ridge : float
        Weight of a small penalty on the deltas (m, rad).  DH cannot represent a tilt between
        parallel axes (UR joints 2-4) except by huge compensating ``d`` and ``θ`` deltas; the
        penalty keeps the deltas physical and leaves that part in the residual instead.

    Returns
    -------
    DhCalibration

    Raises
    ------
    ValueError
        The robot has no standard DH table.
    """
    if robot.dh is None or robot.convention != "dh":
        raise ValueError(f"robot {robot.name!r} has no standard DH table: no DH deltas")
    target_robot = corrected_robot(robot, spec, coeffs)
    rng = np.random.default_rng(seed)
    q = rng.uniform(spec.q_lo, spec.q_hi, size=(n_samples, robot.n_joints))
    T_target = chain(target_robot, q)
    assert isinstance(T_target, np.ndarray)
    w = np.array([1.0, 1.0, 1.0, rot_weight_m, rot_weight_m, rot_weight_m])
    n = robot.n_joints

    reg = ridge * np.sqrt(n_samples)

    def resid(x: F) -> F:
        T = chain(_dh_robot(robot, x), q)
        assert isinstance(T, np.ndarray)
        return np.concatenate([(_pose_diff(T, T_target) * w).ravel(), reg * x])

    def fit_resid(x: F) -> F:
        return resid(x)[: n_samples * 6]

    # Levenberg-Marquardt (MINPACK): DH is ill-conditioned for parallel axes (UR joints 2-4),
    # where an exact representation needs large, mutually compensating d and θ deltas.
    sol = least_squares(
        resid,
        np.zeros(4 * n),
        method="lm",
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
        max_nfev=max_nfev,
    )
    x = sol.x
    r = fit_resid(x).reshape(-1, 6) / w
    r0 = fit_resid(np.zeros(4 * n)).reshape(-1, 6) / w
    return DhCalibration(
        delta_theta=x[:n],
        delta_a=x[n : 2 * n],
        delta_d=x[2 * n : 3 * n],
        delta_alpha=x[3 * n :],
        residual_pos_rms=float(np.sqrt(np.mean(np.sum(r[:, :3] ** 2, 1)))),
        residual_rot_rms=float(np.sqrt(np.mean(np.sum(r[:, 3:] ** 2, 1)))),
        nominal_residual_pos_rms=float(np.sqrt(np.mean(np.sum(r0[:, :3] ** 2, 1)))),
    )


def ur_calibration_text(cal: DhCalibration) -> str:
    """The deltas in the layout of a UR controller's ``calibration.conf`` (SI units)."""

    def vec(v: F) -> str:
        return "[" + ", ".join(f"{x:.12g}" for x in v) + "]"

    return (
        "# quickhealth: kinematics deltas on the nominal DH table (m, rad)\n"
        f"# what DH cannot express: {cal.residual_pos_rms * 1e3:.4f} mm rms position, "
        f"{cal.residual_rot_rms * 1e3:.4f} mrad rms rotation\n"
        "[mounting]\n"
        f"delta_theta = {vec(cal.delta_theta)}\n"
        f"delta_a = {vec(cal.delta_a)}\n"
        f"delta_d = {vec(cal.delta_d)}\n"
        f"delta_alpha = {vec(cal.delta_alpha)}\n"
    )


# ------------------------------------------------------------------ compensate program


@dataclass(frozen=True, eq=False)
class Compensation:
    """Compensated joint targets and the predicted errors before and after (SI).

    ``q`` shape (n, nj) rad; ``error_before_pos``/``residual_pos`` shape (n,) m (modelled TCP
    minus nominal target); ``residual_rot`` (n,) rad; ``converged`` (n,) bool.
    """

    q: F
    error_before_pos: F
    residual_pos: F
    residual_rot: F
    converged: NDArray[np.bool_]
    n_iter: int


def model_tcp(
    robot: RobotModel, spec: ErrorModelSpec, coeffs: ArrayLike, q: ArrayLike, T_flange_tcp: F
) -> F:
    """Modelled TCP pose in the robot base frame (joint errors only), shape (n, 4, 4)."""
    q = np.atleast_2d(np.asarray(q, float))
    m = joint_error_motions(spec, np.asarray(coeffs, float), q)
    E = small_error_transform(m[..., :3], m[..., 3:])
    T = chain(robot, q, E_joint=E)
    assert isinstance(T, np.ndarray)
    return T @ T_flange_tcp


def compensate_joints(
    robot: RobotModel,
    spec: ErrorModelSpec,
    coeffs: ArrayLike,
    q_targets: ArrayLike,
    T_flange_tcp: ArrayLike | None = None,
    *,
    max_iter: int = 10,
    tol_pos: float = 1e-9,
    tol_rot: float = 1e-9,
    step_q: float = 1e-6,
) -> Compensation:
    """Joint targets whose *modelled* TCP pose equals the nominal TCP pose of ``q_targets``.

    Newton iterations, vectorised over targets: the residual is the 6D pose difference
    (position, rotation vector) and the Jacobian comes from central differences of the model.

    Parameters
    ----------
    robot : RobotModel
    spec, coeffs : the identified error model
    q_targets : array, shape (n, nj), rad
        The program's joint targets (what the robot is commanded to today).
    T_flange_tcp : array (4, 4), optional
        The tool centre point on the flange (default the flange itself).
    max_iter, tol_pos (m), tol_rot (rad) : stopping rule
    step_q : float, rad
        Finite-difference step.

    Returns
    -------
    Compensation
    """
    q0 = np.atleast_2d(np.asarray(q_targets, float))
    Tt = np.eye(4) if T_flange_tcp is None else np.asarray(T_flange_tcp, float)
    c = np.asarray(coeffs, float)
    T_goal = chain(robot, q0)
    assert isinstance(T_goal, np.ndarray)
    T_goal = T_goal @ Tt
    n, nj = q0.shape
    q = q0.copy()
    err = _pose_diff(model_tcp(robot, spec, c, q, Tt), T_goal)
    before = np.linalg.norm(err[:, :3], axis=1)
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is reported
        J = np.empty((n, 6, nj))
        for k in range(nj):  # loop over joints (≤ 7), vectorised over targets
            dq = np.zeros(nj)
            dq[k] = step_q
            Tp = model_tcp(robot, spec, c, q + dq, Tt)
            Tm = model_tcp(robot, spec, c, q - dq, Tt)
            J[:, :, k] = _pose_diff(Tp, Tm) / (2 * step_q)
        step = np.einsum("nij,nj->ni", np.linalg.pinv(J, rcond=1e-8), err)
        q = q - step
        err = _pose_diff(model_tcp(robot, spec, c, q, Tt), T_goal)
        if np.all(np.linalg.norm(err[:, :3], axis=1) < tol_pos) and np.all(
            np.linalg.norm(err[:, 3:], axis=1) < tol_rot
        ):
            break
    res_pos = np.linalg.norm(err[:, :3], axis=1)
    res_rot = np.linalg.norm(err[:, 3:], axis=1)
    return Compensation(
        q=q,
        error_before_pos=before,
        residual_pos=res_pos,
        residual_rot=res_rot,
        converged=(res_pos < max(tol_pos, 1e-7)) & (res_rot < max(tol_rot, 1e-7)),
        n_iter=it,
    )


# ---------------------------------------------------------------------- URScript text


def urscript_joint_targets(text: str, n_joints: int) -> tuple[list[tuple[int, int]], F]:
    """Readable joint-list targets ``movej([q1, …, qN], …)`` (also movel/movep/servoj).

    Returns the character spans of the lists' contents and the targets, shape (n, N), rad.
    The tokenizer is :func:`quickhealth.identify.urscript.joint_targets` (comments and strings
    are never targets); moves it cannot read are in its ``unreadable`` list, which a caller
    that rewrites a program must check (``quickhealth compensate`` refuses them).
    """
    t = joint_targets(text, n_joints)
    return list(t.spans), t.q


def urscript_replace_targets(text: str, spans: list[tuple[int, int]], q: ArrayLike) -> str:
    """The program with each joint list at ``spans`` replaced by the row of ``q`` (rad)."""
    return replace_targets(text, spans, q)
