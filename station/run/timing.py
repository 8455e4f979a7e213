"""Where a run's time went, from its journal: does the loop wait for vision?

The 7D measurement of pose k runs in a worker while the arm moves on to pose k+1
(:mod:`.runner`).  Each ``captured`` record says when its pose's move began (``timing.start``,
s since the run's epoch) and when the pair was taken (``time_s``); each ``measured`` record
says when the worker began and ended its work on the pair (``timing.start`` / ``end``: the
images written, the pose measured).  :func:`overlap` sets them side by side.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .journal import JournalState


def overlap(state: JournalState) -> dict[str, Any] | None:
    """The measurement of each pose against the arm's work on the next one.

    Returns (None when the journal has no timings, e.g. an older run):

    ``pairs``: poses k with a measurement and a next pose k+1 in capture order;
    ``overlap_median``: the median fraction of pose k's measurement done while the arm was
    busy with pose k+1 (its move, settling, pan and capture: from its ``timing.start`` to its
    ``time_s``); ``done_before_next_capture``: how many measurements ended before the next
    pose's pair was taken; ``measure_s_median`` / ``arm_s_median``: the worker's time per pose
    and the arm's time per pose (s); ``waited_s``: the time the loop waited on vision in all
    (the part of measurements still running when the next pose's pair was taken).
    """
    order = list(state.captured)  # capture order (a resumed pose: its last capture)
    rows = []
    for k, nxt in zip(order, order[1:], strict=False):
        m, c = state.measured.get(k), state.captured[nxt]
        if m is None or m.timing is None or c.timing is None or "start" not in c.timing:
            continue
        ms, me = float(m.timing["start"]), float(m.timing["end"])
        a0, a1 = float(c.timing["start"]), float(c.time_s)
        if a1 < a0 or me < ms:
            continue  # a resume in between: the clocks of two processes
        inside = max(0.0, min(me, a1) - max(ms, a0))
        rows.append((me - ms, a1 - a0, inside / max(me - ms, 1e-9), me <= a1, max(0.0, me - a1)))
    if not rows:
        return None
    r = np.array(rows, dtype=float)
    return {
        "pairs": len(rows),
        "overlap_median": round(float(np.median(r[:, 2])), 3),
        "done_before_next_capture": int(r[:, 3].sum()),
        "measure_s_median": round(float(np.median(r[:, 0])), 4),
        "arm_s_median": round(float(np.median(r[:, 1])), 4),
        "waited_s": round(float(r[:, 4].sum()), 3),
    }
