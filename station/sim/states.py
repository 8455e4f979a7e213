"""The simulated robot's power states, as a UR controller steps through them.

``power on`` (dashboard) takes a powered-off arm POWER_OFF → BOOTING → POWER_ON → IDLE,
``brake release`` IDLE → RUNNING; ``power off`` or ``restart safety`` go back to POWER_OFF.
Each step takes time (:class:`Delays`: a real arm boots for seconds; tests set them short).
The arm moves only in RUNNING (brakes released) with its safety NORMAL or REDUCED.

Time is the controller's (s, :meth:`Controller.now`): transitions happen when the controller
looks (:meth:`PowerStates.advance`), so nothing here runs a thread.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..hardware.urtypes import RobotMode


@dataclass(frozen=True)
class Delays:
    """How long the controller takes for each step, s (defaults: a real CB3/e-Series arm)."""

    boot_s: float = 3.0  # BOOTING: the joints' firmware starts
    power_on_s: float = 1.5  # POWER_ON before IDLE
    brake_release_s: float = 2.0  # IDLE → RUNNING, the brakes click open
    unlock_after_s: float = 5.0  # a protective stop may be unlocked this long after it began

    @classmethod
    def parse(cls, text: str | None) -> Delays:
        """``"boot=0.2,power_on=0.1,brake_release=0.2,unlock_after=0.5"`` (s; any subset).

        Raises
        ------
        ValueError
            An unknown name or a value that is not a number of seconds in 0..600.
        """
        kw: dict[str, float] = {}
        for item in (text or "").split(","):
            if not item.strip():
                continue
            name, _, val = item.partition("=")
            key = name.strip() + "_s"
            if key not in cls.__dataclass_fields__:
                known = ", ".join(k[:-2] for k in cls.__dataclass_fields__)
                raise ValueError(f"unknown delay {name.strip()!r} (known: {known})")
            try:
                v = float(val)
            except ValueError:
                v = float("nan")
            if not 0.0 <= v <= 600.0:
                raise ValueError(f"delay {name.strip()}: {val.strip()!r} is not 0..600 s")
            kw[key] = v
        return cls(**kw)

    def spec(self) -> str:
        """The :meth:`parse` form of these delays."""
        return ",".join(f"{k[:-2]}={getattr(self, k):g}" for k in self.__dataclass_fields__)


TESTING = Delays(boot_s=0.2, power_on_s=0.1, brake_release_s=0.2, unlock_after_s=0.05)


@dataclass
class PowerStates:
    """The robot mode and its scheduled transitions (see the module docstring)."""

    delays: Delays = field(default_factory=Delays)
    mode: RobotMode = RobotMode.RUNNING
    _schedule: list[tuple[float, RobotMode]] = field(default_factory=list)

    def advance(self, t: float) -> RobotMode:
        """Apply every transition due by controller time ``t``; returns the mode."""
        while self._schedule and self._schedule[0][0] <= t:
            _, self.mode = self._schedule.pop(0)
        return self.mode

    def force(self, mode: RobotMode) -> None:
        """Set the mode at once, cancelling scheduled steps (faults, restarts, tests)."""
        self._schedule.clear()
        self.mode = RobotMode(mode)

    @property
    def busy(self) -> bool:
        """A transition is under way (booting, releasing the brakes)."""
        return bool(self._schedule)

    def power_on(self, t: float) -> bool:
        """Start powering on; False when the arm is not powered off (nothing to do)."""
        self.advance(t)
        if self.mode != RobotMode.POWER_OFF or self._schedule:
            return self.mode in (RobotMode.IDLE, RobotMode.RUNNING) or bool(self._schedule)
        d = self.delays
        self.mode = RobotMode.BOOTING
        self._schedule = [
            (t + d.boot_s, RobotMode.POWER_ON),
            (t + d.boot_s + d.power_on_s, RobotMode.IDLE),
        ]
        return True

    def brake_release(self, t: float) -> bool:
        """Release the brakes of a powered, idle arm; False when it is not powered."""
        self.advance(t)
        if self.mode == RobotMode.RUNNING:
            return True
        if self.mode != RobotMode.IDLE:
            return False
        self._schedule = [(t + self.delays.brake_release_s, RobotMode.RUNNING)]
        return True

    def power_off(self) -> None:
        self.force(RobotMode.POWER_OFF)

    @property
    def powered(self) -> bool:
        return self.mode in (RobotMode.POWER_ON, RobotMode.IDLE, RobotMode.RUNNING)

    @property
    def can_move(self) -> bool:
        return self.mode == RobotMode.RUNNING and not self._schedule
