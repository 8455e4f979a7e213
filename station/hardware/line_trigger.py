"""The line trigger: the robot's standard digital output wired to both cameras' trigger input.

With ``trigger = "line"`` in the cell's ``[cameras]`` section, one pulse on the robot's
standard digital output ``robot_output`` exposes both cameras (their ``trigger_line``, rising
edge).  :class:`LineTrigger` is the ``fire`` hook of the triggered pair
(:class:`~.cameras.genicam.TriggeredStereoCamera`): it asks the robot driver for the pulse
(:meth:`~.robot.UrRobot.pulse_digital_out`: sent only with the arm at rest, each edge
confirmed on the controller's stream) and returns the edge for the capture's journal record
(``camera.edge``: output, the rise on the controller's clock, width, latency, how still the
arm was).  The real station and the simulated cell build it the same way
(:func:`line_trigger`); in the simulated cell a cable carries the controller's output to the
emulated cameras (:mod:`quickhealth.station.sim.cable`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from ...identify.errors import InputError
from .cameras.config import CameraConfig, Trigger


@dataclass(frozen=True)
class Pulse:
    """One pulse on a digital output, as the controller's stream confirmed it.

    Attributes
    ----------
    output : int
        The standard digital output (0..7).
    rise_t, fall_t : float
        Controller time (s, the joint samples' clock) of the first stream packets seen with
        the output high, then low again.
    rise_after_t, fall_after_t : float
        Controller time of the last packets seen before them at the old level: each edge
        lies after this and at or before ``rise_t`` / ``fall_t`` (one controller cycle apart
        when the receiver keeps up; more on a busy computer: it keeps only the latest packet).
    latency_s : float
        From sending the rise to seeing it on the stream (this computer's clock).
    rest_p2p_rad : float
        The joints' largest peak-to-peak motion from the rest window before the rise to the
        fall (rad).
    """

    output: int
    rise_t: float
    fall_t: float
    latency_s: float
    rest_p2p_rad: float
    rise_after_t: float
    fall_after_t: float

    @property
    def width_s(self) -> float:
        """The pulse as the stream showed it (s; at least the width asked)."""
        return self.fall_t - self.rise_t

    def to_json(self) -> dict[str, float | int]:
        """The journal's ``edge`` object (ms and µrad, rounded): ``rise_t`` the first
        controller time seen high, the rise at most ``rise_window_ms`` before it."""
        return {
            "output": self.output,
            "rise_t": round(self.rise_t, 4),
            "rise_window_ms": round((self.rise_t - self.rise_after_t) * 1e3, 1),
            "width_ms": round(self.width_s * 1e3, 1),
            "latency_ms": round(self.latency_s * 1e3, 1),
            "rest_urad": round(self.rest_p2p_rad * 1e6, 2),
        }


@runtime_checkable
class DigitalOutput(Protocol):
    """A robot whose controller drives a standard digital output (the cameras' trigger)."""

    sample_period: float  # s, the controller's stream period

    def pulse_digital_out(self, output: int, width_s: float) -> Pulse:
        """Rise, hold ``width_s`` (controller time), fall, with the arm at rest: refused in
        one line (HardwareError) when it is not, or when an edge is not confirmed."""
        ...


@dataclass(frozen=True)
class LineTrigger:
    """One pulse of ``width_s`` on the robot's standard digital output ``output`` per pair."""

    robot: DigitalOutput
    output: int
    width_s: float

    def __call__(self) -> dict[str, Any]:
        return self.robot.pulse_digital_out(self.output, self.width_s).to_json()


def line_trigger(robot: object, cameras: CameraConfig) -> LineTrigger | None:
    """The ``fire`` hook for ``cameras`` (None unless its trigger is the robot's line).

    Refused in one line (InputError, before anything moves) when the robot driver cannot
    drive a digital output, or the pulse is shorter than two of its controller's cycles (it
    could begin and end inside one cycle and never reach the cameras)."""
    if cameras.trigger is not Trigger.LINE:
        return None
    if not isinstance(robot, DigitalOutput):
        raise InputError(
            f"{cameras.source}: trigger = 'line' needs a robot whose controller drives the "
            "trigger output (a UR over ur-rtde); choose trigger = 'software' or 'external'"
        )
    cycle = float(robot.sample_period)
    if cameras.pulse_s < 2.0 * cycle - 1e-9:
        raise InputError(
            f"{cameras.source}: pulse_ms = {cameras.pulse_s * 1e3:g} is shorter than two "
            f"controller cycles ({2e3 * cycle:.0f} ms at {1.0 / cycle:.0f} Hz): the edge could "
            "be lost inside one cycle"
        )
    return LineTrigger(robot, cameras.robot_output, cameras.pulse_s)
