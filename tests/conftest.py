"""Rules for the whole test session.

``serial``: the tests of real-time behaviour (the simulated controller's stream timing, the
0.5 s freeze check, stop latency, faults and kills in the middle of a move).  ``make test``
runs every other test on two worker processes (pytest-xdist), then these alone, so that they
meet the machine as a station would and no other test competes with them for the two cores.
A module is serial by being listed here.  Kills and signals that only need to land somewhere
(stations killed mid-write, commands stopped while their workers run) are not real-time:
they run with the rest.
"""

from __future__ import annotations

import pytest

SERIAL_MODULES = frozenset(
    {
        "test_robot_ur.py",  # the real ur-rtde client: freeze detection, stop latency
        "test_sim_stream.py",  # 125/500 Hz streams, gaps
        "test_simcontroller.py",
        "test_sim_conformance.py",  # the simulator against UR's documents: streams, delays
        "test_sim_urscript.py",  # the plan's loop program run on the simulator, handshakes
        "test_run.py",  # faults mid-run on the in-process cell
        "test_run_sim.py",  # the simulated cell with the real client, kill -9 and --resume
        "test_line_trigger.py",  # the robot's digital output triggers the emulated cameras
        "test_ur10e_sim.py",  # a UR10e end to end on its simulated cell (500 Hz stream)
        "test_run_cli.py",  # two runs at once, the run lock
        "test_check.py",  # the quick check on the simulated cell, kill -9 and --resume
        "test_tui_sim_cell.py",  # the TUI on the simulated cell, a controller restart
        "test_motor.py",  # serial time-outs
        "test_owner.py",  # device-owner time-outs
    }
)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.name in SERIAL_MODULES:
            item.add_marker(pytest.mark.serial)
