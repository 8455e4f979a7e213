"""UR controller vocabularies shared by the driver and the controller simulator.

The numbers are Universal Robots' own (RTDE ``robot_mode``, ``safety_mode``,
``runtime_state``), so the simulator packs exactly what the driver decodes.  Neither side
defines its own copy.
"""

from __future__ import annotations

from enum import IntEnum


class SafetyMode(IntEnum):
    """UR safety modes (the numbers RTDE reports)."""

    NORMAL = 1
    REDUCED = 2
    PROTECTIVE_STOP = 3
    RECOVERY = 4
    SAFEGUARD_STOP = 5
    SYSTEM_EMERGENCY_STOP = 6
    ROBOT_EMERGENCY_STOP = 7
    VIOLATION = 8
    FAULT = 9
    UNKNOWN = -1


class RobotMode(IntEnum):
    """UR robot modes (the numbers RTDE reports)."""

    DISCONNECTED = 0
    CONFIRM_SAFETY = 1
    BOOTING = 2
    POWER_OFF = 3
    POWER_ON = 4
    IDLE = 5
    BACKDRIVE = 6
    RUNNING = 7
    UPDATING_FIRMWARE = 8
    UNKNOWN = -1


class RuntimeState(IntEnum):
    """State of the program on the controller (RTDE ``runtime_state``)."""

    STOPPING = 0
    STOPPED = 1
    PLAYING = 2
    PAUSING = 3
    PAUSED = 4
    RESUMING = 5


def safety_status_bits(mode: SafetyMode) -> int:
    """RTDE ``safety_status_bits`` of a safety mode (bit 0 normal, 2 protective, 6/7 e-stop)."""
    return {
        SafetyMode.NORMAL: 1 << 0,
        SafetyMode.REDUCED: 1 << 1,
        SafetyMode.PROTECTIVE_STOP: 1 << 2,
        SafetyMode.SAFEGUARD_STOP: 1 << 5,
        SafetyMode.SYSTEM_EMERGENCY_STOP: 1 << 6,
        SafetyMode.ROBOT_EMERGENCY_STOP: (1 << 6) | (1 << 7),
    }.get(SafetyMode(mode), 0)
