"""One loop model: the fit and the diagnosis weight every pose with the same covariance."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from quickhealth.identify.diagnose import state_from_fitted, whitened
from quickhealth.identify.fit import fit_model, linearised
from quickhealth.identify.linearize import InstrumentNoise, noise_covariance
from quickhealth.identify.select import data_spec
from quickhealth.identify.transforms import R_to_rpy, rot_y
from quickhealth.identify.twin import make_twin, random_joints


def _large_yaw_data():
    """Twin data seen by an instrument turned so the target's yaw is about 75°, with per-row
    angle uncertainties (the CSV's ``spitch, syaw, sroll``) of 100 µrad each."""
    twin = make_twin(seed=4)
    meas = twin.measure(random_joints(twin.robot, 80, seed=5), seed=6)
    R = meas.R
    mean = np.linalg.svd(R.mean(0))
    R_mean = mean[0] @ mean[2]
    R0 = rot_y(np.radians(75.0)) @ R_mean.T
    rpy = R_to_rpy(R0[None] @ R)
    return replace(
        meas,
        pos=meas.pos @ R0.T,
        rpy=rpy,
        sigma_pos=np.full((meas.n_poses, 3), 3e-5),
        sigma_rpy=np.full((meas.n_poses, 3), 1e-4),
    )


def test_diagnose_and_fit_use_one_covariance_with_per_row_sigmas_at_large_yaw() -> None:
    meas = _large_yaw_data()
    yaw = np.degrees(meas.rpy[:, 1])
    assert (np.abs(yaw) > 60.0).sum() >= 3
    robot = make_twin(seed=4).robot
    fitted = fit_model(robot, meas, data_spec(robot, meas, order=1))
    lin = linearised(fitted, meas)
    wp = whitened(state_from_fitted(fitted), meas)
    cov_diag = wp.whiten.L @ np.swapaxes(wp.whiten.L, -1, -2)
    # the same covariance, pose by pose, and the same whitened residual
    np.testing.assert_allclose(cov_diag, lin.cov, rtol=1e-9, atol=1e-22)
    np.testing.assert_allclose(wp.r, lin.r, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(cov_diag, noise_covariance(meas, fitted.noise), rtol=1e-9)
    # and it is the Euler-rate mapping, not a plain 100 µrad diagonal: at yaw 75° the
    # rotation-vector axes get very different uncertainties
    i = int(np.argmax(np.abs(yaw)))
    axis_sigma = np.sqrt(np.linalg.eigvalsh(lin.cov[i, 3:, 3:]))
    assert axis_sigma.max() / axis_sigma.min() > 2.0, axis_sigma
    assert not np.allclose(np.diag(lin.cov[i, 3:, 3:]), 1e-8, rtol=0.2, atol=0.0)


def test_instrument_default_is_isotropic_and_encoder_noise_adds_the_joint_directions() -> None:
    meas = _large_yaw_data()
    plain = replace(meas, sigma_rpy=None, sigma_pos=None)
    cov = noise_covariance(plain, InstrumentNoise(sigma_pos=2e-5, sigma_rot=1e-4))
    np.testing.assert_allclose(
        cov[:, 3:, 3:], np.broadcast_to(np.eye(3) * 1e-8, (plain.n_poses, 3, 3))
    )
    np.testing.assert_allclose(
        cov[:, :3, :3], np.broadcast_to(np.eye(3) * 4e-10, (plain.n_poses, 3, 3))
    )


def test_a_joint_motion_perturbation_is_the_error_motion_of_that_joint():
    """Perturbation.joint_motion adds to each joint's six error motions: a constant one equals
    the same change of the joint's order-0 Chebyshev coefficients, and its columns in an
    effect's Jacobian are the frames' motion sensitivities."""
    from quickhealth.identify.effects import Perturbation
    from quickhealth.identify.errormodel import ErrorModelSpec
    from quickhealth.identify.linearize import loop_pose
    from quickhealth.identify.robot import ur5
    from quickhealth.identify.twin import camera_pose, random_joints

    robot = ur5()
    q = random_joints(robot, 12, seed=6)
    spec = ErrorModelSpec.uniform(6, 1, q.min(0) - 0.01, q.max(0) + 0.01)
    c = np.random.default_rng(7).normal(0, 1e-4, spec.n_params)
    T_ft = np.eye(4)
    T_ft[:3, 3] = [0.04, 0.0, 0.06]
    jm = np.zeros((12, 6, 6))
    jm[:, 1, 2], jm[:, 1, 5] = 3e-5, -2e-5  # joint 2: axial growth δz and angle εz
    T1 = loop_pose(robot, spec, c, camera_pose(), T_ft, q, Perturbation(joint_motion=jm))
    c2 = c.copy()
    labels = spec.labels()
    c2[labels.index("j2.dz.c0")] += 3e-5
    c2[labels.index("j2.ez.c0")] -= 2e-5
    T2 = loop_pose(robot, spec, c2, camera_pose(), T_ft, q)
    np.testing.assert_allclose(T1, T2, atol=1e-15)
