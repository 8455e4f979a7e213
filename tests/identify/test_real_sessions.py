"""Two sessions of the shared UR10 (real tracker data, split by goal pose: tests/helpers/qh_real.py)
through the trend's change test: the same robot is unchanged; a joint reading raised by
0.3 mrad is named as that joint's zero offset.  Constant-order fits keep it fast; the BIC-fitted
path through the command line is benchmarks/real_sessions.py's."""

from dataclasses import replace

import pytest
import qh_real as R

from quickhealth.identify.fit import fit_model
from quickhealth.identify.select import data_spec, estimate_noise_scale
from quickhealth.identify.trend import RunState, assess_trend
from quickhealth.station import formats


@pytest.fixture(scope="module")
def sessions():
    robot = formats.load_robot(str(R.UR10_ROBOT))
    a, b = R.ur10_sessions()
    spec = data_spec(robot, a, order=0)
    first = fit_model(robot, a, spec)
    est = estimate_noise_scale(first, a)  # the scatter the real data show
    noise = replace(first.noise, excess_pos=est.excess_pos, excess_rot=est.excess_rot or 0.0)
    fa = fit_model(robot, a, spec, noise=noise)
    return robot, a, b, fa, noise


def _trend(sessions, joint=None):
    robot, a, b, fa, noise = sessions
    if joint is not None:
        q = b.q.copy()
        q[:, joint - 1] += 3e-4
        b = replace(b, q=q)
    fb = fit_model(robot, b, fa.spec, noise=noise)
    n = fa.spec.n_params

    def state(name, f, m, t):
        return RunState(name, t, spec=f.spec, coeffs=f.coeffs, cov=f.cov[:n, :n], model=f, poses=m)

    return assess_trend([state("A", fa, a, 0.0), state("B", fb, b, 86400.0)])


def test_two_sessions_of_the_unchanged_robot_are_not_flagged(sessions):
    res = _trend(sessions)
    assert not res.flags(), res.flags()
    # the sessions measured different poses: the figures are over the baseline's poses
    assert any("measured different poses" in w for w in res.warnings)
    f = res.figures_mm["mean"]
    assert abs(f[1] - f[0]) < 0.05 * f[0], f


@pytest.mark.parametrize("joint", [2, 5])
def test_a_raised_joint_reading_is_named_as_its_zero_offset(sessions, joint):
    res = _trend(sessions, joint)
    (c,) = res.named_changes()
    assert c.fault == f"j{joint}.zero" and abs(c.size + 3e-4) < 2 * c.sigma, c.line()
    assert res.flags()[0] == c.line()
