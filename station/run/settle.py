"""Settle detection: the joint stream shows the arm at rest (never a fixed sleep)."""

from __future__ import annotations

import math
import time
from collections import deque

import numpy as np
from numpy.typing import NDArray

from ...identify.errors import HardwareError
from ..hardware.robot import RobotReader
from .settings import RunSettings

F = NDArray[np.float64]


def is_settled(t: F, Q: F, window_s: float, tol_rad: float, min_samples: int = 5) -> bool:
    """True when the last ``window_s`` of samples ``(t, Q)`` stay within ``tol_rad`` peak to peak.

    Parameters
    ----------
    t : ndarray (m,), s
        Sample times (controller clock, increasing).
    Q : ndarray (m, n), rad
    """
    if len(t) < min_samples or t[-1] - t[0] < window_s:
        return False
    sel = t >= t[-1] - window_s
    if sel.sum() < min_samples:
        return False
    W = Q[sel]
    return bool(np.all(W.max(0) - W.min(0) <= tol_rad))


def wait_settled(
    reader: RobotReader,
    q_target: F,
    settings: RunSettings,
    *,
    poll_s: float | None = None,
) -> tuple[F, float]:
    """Wait until the joint stream shows the arm at rest at ``q_target``.

    Returns the mean joints over the settled window (the recorded reading) and the time
    waited (s).  Raises HardwareError when the arm stays in motion past the timeout or rests
    away from its target.
    """
    if poll_s is None:  # half the stream's sample period (125 Hz on a CB3)
        poll_s = 0.5 * float(getattr(reader, "sample_period", 0.008))
    t0 = time.monotonic()
    ts: deque[float] = deque()
    qs: deque[F] = deque()
    last_t = -math.inf
    while True:
        s = reader.sample()
        if s.t > last_t:
            last_t = s.t
            ts.append(s.t)
            qs.append(s.q)
            while len(ts) > 2 and ts[-1] - ts[1] > settings.settle_window_s:
                ts.popleft()
                qs.popleft()
            T = np.fromiter(ts, float)
            Q = np.array(qs)
            if is_settled(T, Q, settings.settle_window_s, settings.settle_tol_rad):
                qm = Q[T >= T[-1] - settings.settle_window_s].mean(0)
                if np.max(np.abs(qm - q_target)) > 1e-3:
                    raise HardwareError(
                        f"the arm came to rest {np.degrees(np.max(np.abs(qm - q_target))):.3f}° "
                        "away from its target: check the robot, then rerun with --resume"
                    )
                return qm, time.monotonic() - t0
        if time.monotonic() - t0 > settings.settle_timeout_s:
            raise HardwareError(
                f"the arm did not come to rest within {settings.settle_timeout_s:.0f} s "
                "(vibration? a loose tool?): check the robot, then rerun with --resume"
            )
        time.sleep(poll_s)
