"""The simulated controller's digital outputs, as UR's RTDE guide defines them.

The guide's input fields come in pairs, a mask and the levels: ``standard_digital_output_mask``
/ ``standard_digital_output`` (outputs 0..7), ``configurable_digital_output_mask`` /
``configurable_digital_output`` (8..15) and ``tool_digital_output_mask`` /
``tool_digital_output`` (the tool's 0..1).  Only the outputs whose mask bit is set take the
level; the others keep theirs.  ``actual_digital_output_bits`` (UINT64) reads them back: bits
0-7 standard, 8-15 configurable, 16-17 tool.  This is what ur-rtde's
``RTDEIOInterface.setStandardDigitalOut(n, level)`` sends (its input recipe 2: the command
register, the mask ``1 << n`` and the level).

A controller reads its RTDE inputs once per cycle: a change received during cycle ``k`` takes
effect at the start of cycle ``k + 1``, and the first data package showing it carries that
cycle's timestamp.  Two changes of one output inside one cycle leave only the last (a pulse
shorter than a controller cycle may never be seen at the terminal).  URScript's
``set_standard_digital_out`` acts the same way.

Every change is told to the watchers (:meth:`DigitalOutputs.watch`): the simulated cell's
trigger cable (:mod:`.cable`) listens to the terminal this way.  All methods are called
under the controller's lock.
"""

from __future__ import annotations

import queue
from collections.abc import Mapping
from typing import Any

#: (mask field, level field, first bit in ``actual_digital_output_bits``, number of outputs)
MASKED_OUTPUTS = (
    ("standard_digital_output_mask", "standard_digital_output", 0, 8),
    ("configurable_digital_output_mask", "configurable_digital_output", 8, 8),
    ("tool_digital_output_mask", "tool_digital_output", 16, 2),
)

#: A change of the outputs as the watchers get it: (controller time of the cycle it took
#: effect, s; all the output bits after it).
Change = tuple[float, int]


class DigitalOutputs:
    """The controller's digital output terminal (see the module docstring)."""

    def __init__(self) -> None:
        self.bits = 0  # actual_digital_output_bits
        self._pending: list[tuple[float, int, int]] = []  # (effective at, mask, levels)
        self._watchers: list[queue.SimpleQueue[Change | None]] = []
        self.changes = 0  # changes made, for the control channel's state

    def request(self, values: Mapping[str, Any], t_effect: float) -> None:
        """An input package's mask/level pairs, effective at controller time ``t_effect``."""
        for mask_name, level_name, first, n in MASKED_OUTPUTS:
            if mask_name not in values:
                continue
            full = (1 << n) - 1
            mask = int(values[mask_name]) & full
            if mask:
                levels = int(values.get(level_name, 0)) & mask
                self._pending.append((t_effect, mask << first, levels << first))

    def set(self, index: int, level: bool, t_effect: float) -> None:
        """One standard (0..7) or configurable (8..15) output, as URScript sets it."""
        bit = 1 << int(index)
        self._pending.append((t_effect, bit, bit if level else 0))

    def advance(self, t: float) -> None:
        """Apply the changes due by controller time ``t`` (each at its own cycle)."""
        if not self._pending or self._pending[0][0] > t + 1e-9:
            return
        due = [p for p in self._pending if p[0] <= t + 1e-9]
        self._pending = [p for p in self._pending if p[0] > t + 1e-9]
        for te in sorted({p[0] for p in due}):
            bits = self.bits  # the cycle reads its inputs once: the last level of each wins
            for _, mask, levels in (p for p in due if p[0] == te):
                bits = (bits & ~mask) | levels
            if bits != self.bits:
                self.bits = bits
                self.changes += 1
                for w in self._watchers:
                    w.put((te, bits))

    def reset(self, t: float) -> None:
        """Every output low (a controller restart)."""
        self._pending.clear()
        if self.bits:
            self.bits = 0
            self.changes += 1
            for w in self._watchers:
                w.put((t, 0))

    def watch(self) -> queue.SimpleQueue[Change | None]:
        """A queue that receives every change from now on (never blocks the controller)."""
        w: queue.SimpleQueue[Change | None] = queue.SimpleQueue()
        self._watchers.append(w)
        return w

    def unwatch(self, w: queue.SimpleQueue[Change | None]) -> None:
        if w in self._watchers:
            self._watchers.remove(w)
        w.put(None)
