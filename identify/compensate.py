"""Acting on an identified model: corrected kinematics exports and program compensation.

Uses of the fitted model, each a pure function:

1. ``corrected_robot``   the geometric part (each joint's error motions averaged over its
   range, a constant ``E_i``) folded into the robot's constant link transforms, and
   ``urdf_text`` that writes any :class:`RobotModel` as a URDF (joint origins);
2. ``dh_deltas``         UR-style kinematics parameters: ``delta_theta, delta_a, delta_d,
   delta_alpha`` per joint on the manufacturer's DH table, fitted to the corrected kinematics,
   with what DH cannot express reported as a residual; ``ur_calibration_text`` formats them
   (a controller's ``calibration.conf`` layout); ``ur_kinematics_text`` writes the corrected
   kinematics as the UR ROS driver's calibration YAML instead (exact, no DH fit);
   ``export_notes`` says what both leave out (every effect, the base and tool corrections);
3. ``compensate_program`` rewrites a program's joint targets so that the *modelled* TCP lands
   on the nominal target: the joint error model (all Chebyshev orders) and every robot effect
   of the model at each target's own state (backlash by the compensated program's approach
   direction, compliance by the gravity torque, cyclic errors by the phase) and at stated
   conditions (thermal at ``temp_c``, drift at ``time_s``); ``compensate_joints`` is the same
   for a bare joint error model.  ``urscript_joint_targets`` / ``urscript_replace_targets``
   apply it to a URScript program's ``movej([...])``-style joint lists.

What a joint-space compensation corrects, and what not.  It works in the robot's base frame
and on its flange *as the fit identified them* (:func:`model_tcp`: the fit's own loop,
:func:`~quickhealth.identify.linearize.loop_pose`, with the instrument, the base correction
``E0`` and the tool correction ``Etool`` taken out), with the user's tool on the flange.  It
corrects everything that moves the TCP as a function of the commanded joints: the joint
error motions and the effects on joint angles (backlash, compliance, cyclic), link lengths
(thermal) and the base's place (drift), in position and orientation.  It cannot correct what
self-referenced measurements cannot tell from the set-up: a rigid offset of the whole base
(``j1.ez.c0``, ``j1.dz.c0``) and every constant error of the last joint (the measured target's
mounting) are held at zero by the fit and live in ``E0`` / ``Etool``, which describe the
instrument set-up and the target; a cell-frame touch-up and a TCP calibration handle those.
An instrument effect (``depthscale``) is not the robot's error and is never compensated.
No effect can be expressed in a URDF or a DH table: the exports leave them out and say so.

SYNOPSIS::

    robot_c = corrected_robot(robot, spec, coeffs)
    open("corrected.urdf", "w").write(urdf_text(robot_c, comments=export_notes(names)))
    comp = compensate_program(fitted, q_program, T_flange_tcp, temp_c=27.0)
    comp.q, comp.residual_pos      # new targets (rad), remaining predicted error (m)
    comp.effects, comp.left_out    # what was compensated; what not, and why
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any
from xml.sax.saxutils import escape as xml_escape

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from .effects import (
    CHANNELS,
    Effect,
    Perturbation,
    effect_context,
    total_perturbation,
)
from .errormodel import ErrorModelSpec, joint_error_motions
from .errors import InputError
from .fit import FittedModel
from .linearize import forward, joint_angle_jacobian, loop_pose
from .measurements import approach_from_order
from .robot import RobotModel, chain, from_dh, gravity_torques, nominal_of
from .transforms import R_to_rpy, inv_T, log_so3, small_error_transform
from .ur_calibration import KinematicsExport, kinematics_of, kinematics_yaml
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


def export_notes(effects: Sequence[str]) -> list[str]:
    """What a kinematics export (URDF, DH deltas) leaves out, one line each: the model's
    effects by name (first line, when there are any) and the base and tool corrections."""
    out = []
    if effects:
        out.append(
            f"left out of the export: {', '.join(effects)}: effects a URDF or a DH table "
            "cannot express (they depend on the approach, the load, the phase or the "
            "conditions); compensate programs for them with 'quickhealth compensate'"
        )
    out.append(
        "left out of the export: the base and tool corrections (the instrument set-up and "
        "the measured target, not the robot)"
    )
    return out


def _xml_comment(text: str) -> str:
    """``text`` as the body of an XML comment (no ``--``, no control characters)."""
    body = _attr(text).replace("--", "- -")
    return f"<!-- {body} -->"


def urdf_text(robot: RobotModel, *, name: str | None = None, comments: Sequence[str] = ()) -> str:
    """A URDF of the robot's kinematics: revolute joints about z, origins from the link transforms.

    Joint i's origin is ``C_{i-1} · Rz(o_i)`` (the zero offset folded in); a fixed joint to
    ``flange`` carries ``C_n``.  Link masses and centres of mass are written when known.
    URDF ``rpy`` is fixed-axis x-y-z: ``R = Rz(y) · Ry(p) · Rx(r)``.  ``comments`` are written
    as XML comments after the declaration (e.g. :func:`export_notes`).
    """
    nj = robot.n_joints
    names = list(robot.joint_names) or [f"j{i + 1}" for i in range(nj)]
    lines = [
        '<?xml version="1.0"?>',
        *(_xml_comment(c) for c in comments),
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


def ur_calibration_text(cal: DhCalibration, notes: Sequence[str] = ()) -> str:
    """The deltas in the layout of a UR controller's ``calibration.conf`` (SI units);
    ``notes`` become comment lines (e.g. :func:`export_notes`)."""

    def vec(v: F) -> str:
        return "[" + ", ".join(f"{x:.12g}" for x in v) + "]"

    extra = "".join("# " + " ".join(n.split()) + "\n" for n in notes)
    return (
        "# quickhealth: kinematics deltas on the nominal DH table (m, rad)\n"
        f"# what DH cannot express: {cal.residual_pos_rms * 1e3:.4f} mm rms position, "
        f"{cal.residual_rot_rms * 1e3:.4f} mrad rms rotation\n" + extra + "[mounting]\n"
        f"delta_theta = {vec(cal.delta_theta)}\n"
        f"delta_a = {vec(cal.delta_a)}\n"
        f"delta_d = {vec(cal.delta_d)}\n"
        f"delta_alpha = {vec(cal.delta_alpha)}\n"
    )


def ur_kinematics_text(
    robot: RobotModel,
    spec: ErrorModelSpec,
    coeffs: ArrayLike,
    notes: Sequence[str] = (),
) -> tuple[str, KinematicsExport]:
    """The corrected kinematics (:func:`corrected_robot`) as the UR ROS driver's calibration
    YAML (:mod:`.ur_calibration`): the file ``ur_calibration`` writes and ur_description's URDF
    reads, so ROS, a planner and ``--calibration`` use the same kinematics.

    The joint frames are placed like those of ``robot`` (the nominal model: its DH layout, or
    the controller calibration it was read from), so the URDF's links and meshes stay where
    they were.  What the layout cannot hold (a tilted or offset flange: a tool error) is left
    out and said in the header, with ``notes`` (e.g. :func:`export_notes`).

    Raises
    ------
    ValueError
        The robot does not have six joints.
    """
    rc = corrected_robot(robot, spec, coeffs)
    ex = kinematics_of(rc, reference=robot)
    head = [
        "quickhealth: corrected kinematics (the identified constant joint errors) in the "
        "layout of the UR ROS driver's ur_calibration (kinematics_params of ur_description)",
        f"nominal: {nominal_of(robot)}",
        "lengths m, angles rad as ur_calibration writes them: R = Rx(roll) * Ry(pitch) * "
        f"Rz(yaw); read as URDF origin rpy (Rz * Ry * Rx) the flange moves at most "
        f"{ex.urdf_pos * 1e3:.4f} mm, {ex.urdf_rot * 1e3:.4f} mrad",
    ]
    if ex.flange_pos > 1e-9 or ex.flange_rot > 1e-9:
        head.append(
            f"left out of the export: the flange offset the layout cannot hold "
            f"({ex.flange_pos * 1e3:.4f} mm, {ex.flange_rot * 1e3:.4f} mrad): it belongs to "
            "the tool's TCP"
        )
    return kinematics_yaml(ex.kinematics, [*head, *notes]), ex


# ------------------------------------------------------------------ compensate program


#: How a compensated program's joint torques are taken (a program has no measured torques).
TORQUE_FROM_MASSES = "the torque holding the robot model's masses"

#: Why an instrument effect is never compensated (the printed and documented reason).
INSTRUMENT_REASON = (
    "an instrument effect: it is how the camera measures, not where the robot goes; "
    "nothing for a robot program to correct"
)


@dataclass(frozen=True, eq=False)
class Compensation:
    """Compensated joint targets and the predicted errors before and after (SI).

    ``q`` shape (n, nj) rad; ``error_before_pos``/``residual_pos`` shape (n,) m (modelled TCP
    minus nominal target); ``residual_rot`` (n,) rad; ``converged`` (n,) bool.  With effects
    (:func:`compensate_program`): ``approach`` (n, nj) the ±1 approach directions used (those
    of the compensated program), ``approach_settled`` (n,) False where they did not settle
    (the correction flips the direction the program moves a backlash joint in); ``effects``
    the compensated effects, ``left_out`` the others with the reason; ``temp_c`` / ``time_s``
    the conditions used (None when no compensated effect needs them).
    """

    q: F
    error_before_pos: F
    residual_pos: F
    residual_rot: F
    converged: NDArray[np.bool_]
    n_iter: int
    error_before_rot: F | None = None
    approach: F | None = None
    approach_settled: NDArray[np.bool_] | None = None
    effects: tuple[str, ...] = ()
    left_out: tuple[tuple[str, str], ...] = ()
    temp_c: float | None = None
    time_s: float | None = None
    described: tuple[str, ...] = ()  # one phrase per compensated effect: what it used


def joint_coefficients(spec: ErrorModelSpec, coeffs: ArrayLike) -> F:
    """``coeffs`` with the base and tool corrections set to zero (the robot's own errors)."""
    c = np.array(coeffs, dtype=float)
    frame = spec.index()[:, 0]
    c[(frame == 0) | (frame == spec.n_joints + 1)] = 0.0
    return c


def model_tcp(
    robot: RobotModel,
    spec: ErrorModelSpec,
    coeffs: ArrayLike,
    q: ArrayLike,
    T_flange_tcp: F,
    pert: Perturbation | None = None,
) -> F:
    """Modelled TCP pose in the robot's (identified) base frame, shape (n, 4, 4).

    The fit's own loop (:func:`~quickhealth.identify.linearize.loop_pose`) with the instrument,
    the base and the tool correction taken out: every joint's error motions, plus the robot
    side of the effects' perturbation ``pert`` (joint angles, link lengths, base motion; an
    instrument depth scale is not applied).
    """
    q = np.atleast_2d(np.asarray(q, float))
    c = joint_coefficients(spec, coeffs)
    p = Perturbation() if pert is None else replace(pert, instr_scale_z=None)
    return loop_pose(robot, spec, c, np.eye(4), np.asarray(T_flange_tcp, float), q, p)


def pose_error(T: F, T_goal: F) -> F:
    """Pose minus goal, shape (n, 6): position (m) and the rotation vector ``log(R R_goalᵀ)``
    (rad), both in the frame the poses are given in."""
    dw = log_so3(T[:, :3, :3] @ np.swapaxes(T_goal[:, :3, :3], -1, -2))
    return np.concatenate([T[:, :3, 3] - T_goal[:, :3, 3], dw], axis=1)


PerturbFn = Callable[[F, F], Perturbation]

#: Largest change of any joint in one Newton step (rad): ten times any correction a program
#: would accept (``compensate --max-correction-deg`` allows at most 10°).
MAX_STEP = 0.2


@dataclass(frozen=True, eq=False)
class _Frames:
    """Where the modelled TCP sits: ``left · loop(coeffs, right) · post`` in the base frame
    the program's poses are written in.  Without a fitted model: the joint coefficients only
    in the identified base frame (``left = I``, ``right`` the TCP).  With one: the whole loop
    (base, tool, joints) seen from the registered base and tool
    (:attr:`~quickhealth.identify.fit.FittedModel.registration`), so the compensation does
    not depend on how the fit split error between base, tool and joint constants."""

    coeffs: F
    left: F
    right: F
    post: F

    def tcp(self, robot: RobotModel, spec: ErrorModelSpec, q: F, pert: Perturbation) -> F:
        """Modelled TCP poses (n, 4, 4)."""
        return loop_pose(robot, spec, self.coeffs, self.left, self.right, q, pert) @ self.post

    def forward(
        self, robot: RobotModel, spec: ErrorModelSpec, q: F, pert: Perturbation
    ) -> tuple[F, F]:
        """Modelled TCP poses and the loop's frames before every error transform."""
        T, A, _ = forward(robot, spec, self.coeffs, self.left, self.right, q, pert)
        assert A is not None
        return T @ self.post, A


def _newton(
    robot: RobotModel,
    spec: ErrorModelSpec,
    frames: _Frames,
    T_goal: F,
    q_start: F,
    perturb: PerturbFn,
    approach: F,
    max_iter: int,
    tol_pos: float,
    tol_rot: float,
) -> tuple[F, F, int]:
    """Newton iterations on the modelled TCP, vectorised over targets.

    The Jacobian is the loop's analytic joint-angle Jacobian ``[z × (p − o), z]`` at the
    perturbed angles (:func:`~quickhealth.identify.linearize.joint_angle_jacobian`); the
    derivatives of the small error motions and of the effects with respect to the command
    (≲ 1e-3 of it) are left out, so the iteration contracts by about that factor per step.
    """
    q = q_start.copy()
    it = 0
    err = np.zeros((q.shape[0], 6))
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is reported
        T, A = frames.forward(robot, spec, q, perturb(q, approach))
        err = pose_error(T, T_goal)
        if np.all(np.linalg.norm(err[:, :3], axis=1) < tol_pos) and np.all(
            np.linalg.norm(err[:, 3:], axis=1) < tol_rot
        ):
            return q, err, it - 1
        J = np.swapaxes(joint_angle_jacobian(T, A), 1, 2)  # (n, 6, nj)
        step = np.einsum("nij,nj->ni", np.linalg.pinv(J, rcond=1e-8), err)
        # near a singularity the step grows without bound: keep it to a correction's size
        # (the target then does not converge and is reported, never jumps to another branch)
        size = np.abs(step).max(axis=1, keepdims=True)
        q = q - step * np.minimum(1.0, MAX_STEP / np.maximum(size, 1e-300))
    T = frames.tcp(robot, spec, q, perturb(q, approach))
    return q, pose_error(T, T_goal), it


def _solve(
    robot: RobotModel,
    spec: ErrorModelSpec,
    coeffs: ArrayLike,
    q_targets: ArrayLike,
    T_flange_tcp: ArrayLike | None,
    perturb: PerturbFn,
    approach: F | None,
    backlash_joints: Sequence[int],
    *,
    max_iter: int,
    tol_pos: float,
    tol_rot: float,
    approach_rounds: int,
    fitted: FittedModel | None = None,
) -> Compensation:
    """The compensation core: Newton per approach round until the approach settles."""
    q0 = np.atleast_2d(np.asarray(q_targets, float))
    Tt = np.eye(4) if T_flange_tcp is None else np.asarray(T_flange_tcp, float)
    if fitted is None:
        frames = _Frames(joint_coefficients(spec, coeffs), np.eye(4), Tt, np.eye(4))
    else:
        T_rb, T_rt = fitted.registration
        frames = _Frames(
            np.asarray(fitted.coeffs, float),
            inv_T(T_rb) @ fitted.T_instr_base0,
            np.asarray(fitted.T_flange_target0, float),
            inv_T(T_rt) @ Tt,
        )
    T_goal = robot.fk(q0).reshape(-1, 4, 4) @ Tt  # nominal kinematics
    fixed = approach is not None
    app = approach_from_order(q0) if approach is None else np.asarray(approach, float)
    before = pose_error(frames.tcp(robot, spec, q0, perturb(q0, app)), T_goal)
    bj = list(backlash_joints)
    q, err, n_it = q0, before, 0
    settled = np.ones(len(q0), bool)
    rounds = max(approach_rounds, 1)
    for r in range(rounds):
        q, err, it = _newton(
            robot, spec, frames, T_goal, q, perturb, app, max_iter, tol_pos, tol_rot
        )
        n_it += it
        if fixed or not bj:
            break
        # the robot approaches each target from the previous *compensated* one
        app_new = approach_from_order(q)
        settled = ~np.any(app_new[:, bj] != app[:, bj], axis=1)
        if settled.all() or r == rounds - 1:
            break
        app = app_new
    res_pos = np.linalg.norm(err[:, :3], axis=1)
    res_rot = np.linalg.norm(err[:, 3:], axis=1)
    return Compensation(
        q=q,
        error_before_pos=np.linalg.norm(before[:, :3], axis=1),
        residual_pos=res_pos,
        residual_rot=res_rot,
        converged=(res_pos < max(tol_pos, 1e-7)) & (res_rot < max(tol_rot, 1e-7)),
        n_iter=n_it,
        error_before_rot=np.linalg.norm(before[:, 3:], axis=1),
        approach=app,
        approach_settled=settled,
    )


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
) -> Compensation:
    """Joint targets whose *modelled* TCP pose equals the nominal TCP pose of ``q_targets``.

    The joint error model only (no effects; see :func:`compensate_program` for a fitted model
    with its effects).  Newton iterations, vectorised over targets: the residual is the 6D
    pose difference (position, rotation vector), the Jacobian the loop's joint-angle Jacobian.

    Parameters
    ----------
    robot : RobotModel
    spec, coeffs : the identified error model (base and tool corrections are not used)
    q_targets : array, shape (n, nj), rad
        The program's joint targets (what the robot is commanded to today).
    T_flange_tcp : array (4, 4), optional
        The tool centre point on the flange (default the flange itself).
    max_iter, tol_pos (m), tol_rot (rad) : stopping rule

    Returns
    -------
    Compensation
    """
    return _solve(
        robot,
        spec,
        coeffs,
        q_targets,
        T_flange_tcp,
        lambda q, a: Perturbation(),
        None,
        (),
        max_iter=max_iter,
        tol_pos=tol_pos,
        tol_rot=tol_rot,
        approach_rounds=1,
    )


def compensate_program(
    fitted: FittedModel,
    q_targets: ArrayLike,
    T_flange_tcp: ArrayLike | None = None,
    *,
    temp_c: float | None = None,
    time_s: float | None = None,
    joint_temp_c: float | Sequence[float] | None = None,
    leave_out: Sequence[str] = (),
    approach: ArrayLike | None = None,
    max_iter: int = 12,
    tol_pos: float = 1e-9,
    tol_rot: float = 1e-9,
    approach_rounds: int = 6,
) -> Compensation:
    """A program's joint targets compensated with the whole fitted model: joint errors and
    every robot effect, at each target's own state and the stated conditions.

    Solves, per target and vectorised over all of them, for the command whose modelled TCP
    pose (:func:`model_tcp`: joint error motions + the effects' joint-angle, link-length and
    base perturbations, in the identified base frame) equals the nominal TCP pose of the
    original target.  What each effect contributes at a target:

    - ``backlash:jK`` (any effect that needs the ``approach`` channel): ``± b/2`` by the
      direction the program moves joint K into the target.
      The program runs in the order given, so the approach is that of the *compensated*
      program (the previous compensated target), recomputed until it settles
      (``approach_rounds``); the first target, and joints that do not move, follow the fit's
      rule (:func:`~quickhealth.identify.measurements.approach_from_order`: the last move's
      direction, from below before any move).  ``approach`` (n, nj) overrides it.
    - ``compliance:jK`` (mass or lumped form): the gravity torque at the compensated command.
    - ``cyclic:jK:hM``: the phase ``M q_K`` at the compensated command.
    - ``thermal``: the links grown to ``temp_c`` (°C); ``drift``: the base moved to its place at
      ``time_s`` (s on the fitted run's clock).  Both must be given when the effect is
      compensated: a program is run at the conditions its user states.  So must
      ``joint_temp_c`` (°C: one for every joint, or one per joint) for an effect of the joints'
      temperatures.
    - an effect of the measured joint torques: the torque that holds the robot model's link
      masses against gravity at each compensated command (a program has no measured torques;
      a robot model without masses cannot model them, and such an effect must be left out).
    - an instrument effect (``depthscale``: :attr:`~.effects.Effect.instrument`) is never
      compensated (:data:`INSTRUMENT_REASON`).

    Each compensated effect says in :attr:`Compensation.described` what it used
    (:meth:`~.effects.Effect.correction`).

    Parameters
    ----------
    fitted : FittedModel
    q_targets : array (n, nj), rad, in program order
    T_flange_tcp : array (4, 4), optional
        The tool centre point on the flange (default the flange).
    temp_c, time_s : float, optional
        Conditions the program runs at (needed by ``thermal`` / ``drift``).
    joint_temp_c : float or sequence of float, optional
        The joints' temperature the program runs at (°C; needed by ``thermal:jK``).
    leave_out : sequence of str
        Effect names of the model not to compensate.

    Returns
    -------
    Compensation

    Raises
    ------
    InputError
        An unknown name in ``leave_out``; a compensated effect whose condition is not given.
    """
    robot = fitted.robot
    q0 = np.atleast_2d(np.asarray(q_targets, float))
    names = [e.name for e in fitted.effects]
    unknown = [n for n in leave_out if n not in names]
    if unknown:
        have = ", ".join(names) or "none"
        raise InputError(f"cannot leave out {', '.join(unknown)}: the model's effects are {have}")
    # the conditions the program runs at, by channel (approach: the program's order)
    nj = robot.n_joints
    has_masses = robot.masses is not None and robot.coms is not None
    given: dict[str, Any] = {
        "temp": None if temp_c is None else float(temp_c),
        "time": None if time_s is None else float(time_s),
        "joint_temp": None
        if joint_temp_c is None
        else tuple(np.broadcast_to(np.asarray(joint_temp_c, float), (nj,)).tolist()),
        "joint_torque": TORQUE_FROM_MASSES if has_masses else None,
    }
    used: list[tuple[Effect, F]] = []
    left: list[tuple[str, str]] = []
    for e, p in zip(fitted.effects, fitted.effect_params, strict=True):
        if e.name in leave_out:
            left.append((e.name, "left out on request"))
            continue
        if e.instrument:
            left.append((e.name, INSTRUMENT_REASON))
            continue
        for col in e.requires():
            if col == "joint_torque" and given[col] is None:
                raise InputError(
                    f"effect {e.name!r} needs the torque measured at each target, which a "
                    f"program does not have, and robot {robot.name!r} has no link masses to "
                    "model it from: leave it out"
                )
            if col != "approach" and given.get(col) is None:
                raise InputError(
                    f"effect {e.name!r} needs the {CHANNELS[col].words} the program runs at, or "
                    "leave it out"
                )
        used.append((e, np.asarray(p, float)))
    # joints whose correction depends on the direction the program moves them into a target
    approach_joints = sorted({e.joint for e, _ in used if "approach" in e.requires()})

    def perturb(q: F, app: F) -> Perturbation:
        if not used:
            return Perturbation()
        n = len(q)
        at = {k: None if given[k] is None else np.full(n, given[k]) for k in ("time", "temp")}
        jt = given["joint_temp"]
        ctx = effect_context(
            robot,
            q,
            app,
            at["time"],
            at["temp"],
            joint_temp=None if jt is None else np.tile(jt, (n, 1)),
            joint_torque=-gravity_torques(robot, q) if has_masses else None,
        )
        return total_perturbation([e for e, _ in used], [p for _, p in used], ctx)

    comp = _solve(
        robot,
        fitted.spec,
        fitted.coeffs,
        q0,
        T_flange_tcp,
        perturb,
        None if approach is None else np.asarray(approach, float),
        approach_joints,
        max_iter=max_iter,
        tol_pos=tol_pos,
        tol_rot=tol_rot,
        approach_rounds=approach_rounds,
        fitted=fitted,
    )
    needs = {col for e, _ in used for col in e.requires()}
    return replace(
        comp,
        effects=tuple(e.name for e, _ in used),
        left_out=tuple(left),
        temp_c=float(temp_c) if "temp" in needs and temp_c is not None else None,
        time_s=float(time_s) if "time" in needs and time_s is not None else None,
        described=tuple(e.correction(given) for e, _ in used),
    )


def fitted_tool(fitted: FittedModel) -> F:
    """The measurement target on the flange of the registered nominal robot (4, 4): the TCP
    to compensate when the program's tool is the measured target."""
    return fitted.registration[1]


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
