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
