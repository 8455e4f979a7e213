"""The simulated cell's hardware: a UR controller simulator and a pure-Python fake robot.

The unmodified ur-rtde client (``rtde_receive``, ``rtde_control``) connects to the
controller simulator exactly as to a real controller (``notes/ur-rtde.md``).  Modules, one
job each:

- ``wire``: RTDE packet format, the RTDE guide's field names and types, recipes, ports,
  controller versions, protocol versions
- ``arm``: the motion model (trapezoids, timed motions, straight-line path planning with
  the analytic UR IK, ringing after stops, encoder noise)
- ``kinematics``: the controller's factory calibration, joint limits, the checks that turn
  a bad move into a protective stop
- ``dynamics``: joint torques (Newton-Euler on the arm's link masses), currents, temperatures
- ``states``: power states (POWER_OFF → BOOTING → POWER_ON → IDLE → RUNNING) and their delays
- ``controller``: safety and program state, the emulated ``rtde_control`` register
  protocol, the planner thread, fault injection
- ``dashboard``: the dashboard command table of CB3 3.x and e-Series 5.x
- ``primary``: the primary, secondary and realtime interfaces (URScript in, messages out)
- ``urscript_vm``, ``urscript_program``: the URScript interpreter and a program's thread
- ``servers``: RTDE (30004), dashboard (29999), 30001-30003 and the JSON control port
  (default 30090), all on 127.0.0.1 only
- ``process``: :func:`~.process.start_sim_controller`, :class:`~.process.SimControllerHandle`,
  the host-wide port lock and the command line
- ``fake_robot``: :class:`~.fake_robot.FakeRobot`, the arm behind the driver's interface
  in this process (unit tests, the TUI's in-process cell)

The RTDE stream never waits on path planning: each stream thread holds the controller lock
only to copy state, on absolute deadlines at the requested rate (125 Hz for a CB3 version,
500 Hz for an e-Series one).  The arm is the cell's (``--cell``): its kinematics, own joint
limits and joint speed limits; the version it reports is that arm's generation's unless
``--controller-version`` says otherwise (3.15.7 CB3, 5.11.1 e-Series).

Faults (control port ``{"cmd": "fault", "kind": ...}``, now, ``after_s`` or
``after_moves``): ``protective_stop``, ``emergency_stop``, ``program_stop``,
``freeze_stream``, ``drop_connection``, ``restart`` (every link dropped, connections
refused for ``down_s`` s, program stopped, registers reset), ``slow_program_start``
(``delay_s``: an uploaded script runs that long after it arrived), ``power_off``,
``pause``, ``joint_speed_limit`` (``scale``: the next move beyond the lowered limits is a
protective stop), ``unknown_command`` (the control program stops with a compile error) and
``clear``.  Beyond these the controller raises faults of its own, as a real one: moves
beyond the joint limits or out of reach end in a protective stop.  The
control port's ``state`` lists the stop commands received (``stopj``, ``dashboard`` …) with
their ``time.monotonic()`` (the host's clock, shared by every process): stop latency.

Nothing here is imported by the drivers in :mod:`quickhealth.station.hardware`; the drivers
talk to the simulator over the same sockets as to a real controller.

Run ``python -m quickhealth.station.sim --help``.
"""
