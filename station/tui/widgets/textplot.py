"""Terminal plots: text histograms and bars that read well in 80 columns over SSH.

Pure functions from numbers to strings (Rich markup where noted); the curve and trend plots
use ``textual_plotext.PlotextPlot`` directly in the screens.
"""

from __future__ import annotations

from collections.abc import Sequence

BLOCKS = " ▁▂▃▄▅▆▇█"


def spark(counts: Sequence[float], width: int | None = None) -> str:
    """One-line histogram of ``counts`` with block characters (resampled to ``width``)."""
    vals = [float(c) for c in counts]
    if width is not None and vals and width != len(vals):
        vals = [vals[min(len(vals) - 1, int(i * len(vals) / width))] for i in range(width)]
    top = max(vals, default=0.0)
    if top <= 0:
        return BLOCKS[0] * len(vals)
    return "".join(BLOCKS[min(8, round(8 * v / top))] if v > 0 else "·" for v in vals)


def bar(fraction: float, width: int = 20) -> str:
    """A horizontal bar of ``width`` cells filled to ``fraction`` (clipped to [0, 1])."""
    f = min(1.0, max(0.0, fraction))
    full = int(f * width)
    part = int((f * width - full) * 8)
    tail = "▏▎▍▌▋▊▉"[part - 1] if part > 0 and full < width else ""
    return ("█" * full + tail).ljust(width, "·")


def fmt_duration(seconds: float | None) -> str:
    """``1 min 05 s`` style, or ``–`` when unknown."""
    if seconds is None:
        return "–"
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    m, s = divmod(s, 60)
    if m < 60:
        return f"{m} min {s:02d} s"
    h, m = divmod(m, 60)
    return f"{h} h {m:02d} min"
