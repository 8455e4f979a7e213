"""Approach directions from execution order (CSV v1: taken from the previous row)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from quickhealth.identify.measurements import Measurements, approach_from_order


def _reference(q: np.ndarray) -> np.ndarray:
    """The rule written as a plain loop: carry each joint's last move direction forward."""
    out = np.empty_like(q)
    last = np.ones(q.shape[1])
    prev = q[0]
    for i, row in enumerate(q):
        d = np.sign(row - prev)
        last = np.where(d != 0, d, last)
        out[i] = last
        prev = row
    return out


@settings(max_examples=50, deadline=None)
@given(
    st.lists(
        st.lists(st.sampled_from([-1.0, 0.0, 0.5, 2.0]), min_size=3, max_size=3),
        min_size=1,
        max_size=12,
    )
)
def test_vectorised_rule_equals_the_loop(rows) -> None:
    q = np.array(rows)
    np.testing.assert_array_equal(approach_from_order(q), _reference(q))


def test_measurements_use_the_same_rule() -> None:
    q = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, -1.0], [0.5, -1.0]])
    m = Measurements(q=q, pos=np.zeros((4, 3)))
    np.testing.assert_array_equal(m.approach_sign(), [[1, 1], [1, 1], [1, -1], [-1, -1]])
