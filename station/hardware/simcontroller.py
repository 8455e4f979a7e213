"""Compatibility names for the UR controller simulator, which lives in :mod:`quickhealth.station.sim`.

Older imports (``from quickhealth.station.hardware.simcontroller import start_sim_controller``)
keep working; new code imports from the package's modules.  The mode constants are aliases
of the driver's enums in :mod:`.urtypes`.  ``python -m quickhealth.station.hardware.simcontroller``
runs the simulator like ``python -m quickhealth.station.sim``.
"""

from __future__ import annotations

from quickhealth.station.sim.arm import (
    HOME_Q_DEG,
    Arm,
    Motion,
    T_from_pose,
    ik_dls,
    pose_from_T,
    trapezoid_duration,
    trapezoid_fraction,
)
from quickhealth.station.sim.controller import (
    CMD_MOVEJ,
    CMD_MOVEJ_IK,
    CMD_MOVEL,
    CMD_MOVEL_FK,
    CMD_NONE,
    CMD_STOP_SCRIPT,
    CMD_STOPJ,
    CMD_STOPL,
    FAULT_KINDS,
    Controller,
)
from quickhealth.station.sim.process import (
    PORT_LOCK,
    SimControllerHandle,
    add_arguments,
    build_controller,
    main,
    ports_free,
    run_from_args,
    start_sim_controller,
)
from quickhealth.station.sim.servers import serve
from quickhealth.station.sim.wire import (
    CONTROL_PORT,
    CONTROLLER_VERSION,
    DASHBOARD_PORT,
    HOST,
    RTDE_PORT,
    SCRIPT_PORT,
    rtde_type,
)

from .urtypes import RobotMode, RuntimeState, SafetyMode

ROBOT_MODE_POWER_OFF = RobotMode.POWER_OFF
ROBOT_MODE_IDLE = RobotMode.IDLE
ROBOT_MODE_RUNNING = RobotMode.RUNNING
SAFETY_NORMAL = SafetyMode.NORMAL
SAFETY_PROTECTIVE_STOP = SafetyMode.PROTECTIVE_STOP
SAFETY_ROBOT_EMERGENCY_STOP = SafetyMode.ROBOT_EMERGENCY_STOP
RUNTIME_STOPPED = RuntimeState.STOPPED
RUNTIME_PLAYING = RuntimeState.PLAYING
RUNTIME_PAUSED = RuntimeState.PAUSED

__all__ = [
    "CMD_MOVEJ",
    "CMD_MOVEJ_IK",
    "CMD_MOVEL",
    "CMD_MOVEL_FK",
    "CMD_NONE",
    "CMD_STOPJ",
    "CMD_STOPL",
    "CMD_STOP_SCRIPT",
    "CONTROLLER_VERSION",
    "CONTROL_PORT",
    "DASHBOARD_PORT",
    "FAULT_KINDS",
    "HOME_Q_DEG",
    "HOST",
    "PORT_LOCK",
    "ROBOT_MODE_IDLE",
    "ROBOT_MODE_POWER_OFF",
    "ROBOT_MODE_RUNNING",
    "RTDE_PORT",
    "RUNTIME_PAUSED",
    "RUNTIME_PLAYING",
    "RUNTIME_STOPPED",
    "SAFETY_NORMAL",
    "SAFETY_PROTECTIVE_STOP",
    "SAFETY_ROBOT_EMERGENCY_STOP",
    "SCRIPT_PORT",
    "Arm",
    "Controller",
    "Motion",
    "SimControllerHandle",
    "T_from_pose",
    "add_arguments",
    "build_controller",
    "ik_dls",
    "main",
    "pose_from_T",
    "ports_free",
    "rtde_type",
    "run_from_args",
    "serve",
    "start_sim_controller",
    "trapezoid_duration",
    "trapezoid_fraction",
]

if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
