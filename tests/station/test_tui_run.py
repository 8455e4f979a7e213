"""The TUI at the simulated cell: a whole run from pre-flight to results, abort, connection loss.

Driven with textual's pilot through the real facade, ``station.run.run_plan``, the pure-Python
FakeRobot, the serial pan-motor emulator and the rendered stereo cameras (small images).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from qh_tui import ended, journal_indices, run_until_first_pose, settle, start_run, text, wait_for

from quickhealth.station.planning import load_cell
from quickhealth.station.run.journal import JOURNAL, iter_records, read_journal
from quickhealth.station.tui.app import QuickhealthApp
from quickhealth.station.tui.facade import Facade, make_plan
from quickhealth.station.tui.screens.confirm import ConfirmScreen
from quickhealth.station.tui.simulated import in_process


@pytest.fixture(scope="module")
def plan():  # type: ignore[no-untyped-def]
    """A short frozen plan of the reference cell (planned once for the module)."""
    p = make_plan(load_cell("reference"), 14, 3)
    assert 7 <= len(p.poses) <= 10  # the constant model needs 7 full-pose poses
    return p


def sim_station(tmp: Path, plan) -> Facade:  # type: ignore[no-untyped-def]
    return in_process(tmp / "archive", plan=plan, max_order=1, threshold_mm=5.0)


@pytest.mark.slow
async def test_whole_run_from_preflight_to_results(tmp_path: Path, plan) -> None:  # type: ignore[no-untyped-def]
    station = sim_station(tmp_path, plan)
    n = len(plan.poses)
    app = QuickhealthApp(station)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(app, pilot)
        assert "GO" in text(app, "#verdict") and "NO-GO" not in text(app, "#verdict")
        conns = app.screen.query_one("#connections")
        rows = [[str(c) for c in conns.get_row_at(i)] for i in range(conns.row_count)]
        assert len(rows) == 3 and all("ok" in r[1] for r in rows), rows
        checks = app.screen.query_one("#checks")
        assert checks.row_count >= 5
        assert all("✓" in str(checks.get_row_at(i)[1]) for i in range(checks.row_count))

        await pilot.press("2")
        await settle(app, pilot)
        assert f"kept          {n}" in text(app, "#plan-summary").replace("[green]", "")
        assert text(app, "#coverage").count("%") == 6
        await pilot.press("d")
        await settle(app, pilot)
        assert "Dry run OK" in text(app, "#dry-run")

        await pilot.press("3")
        await settle(app, pilot)
        assert app.screen.query_one("#poses").row_count == n
        await start_run(app, pilot)
        await wait_for(
            app, pilot, lambda: app.screen.progress is not None and app.screen.progress.done >= 1
        )
        mid = app.screen.progress
        assert mid.state == "running" and mid.eta_s is not None and mid.current is not None
        await wait_for(app, pilot, lambda: ended(app))
        await settle(app, pilot)
        final = app.screen.progress
        assert final.state == "finished" and final.done == n
        assert "markers" in text(app, "#run-last") and "px" in text(app, "#run-last")
        table = app.screen.query_one("#poses")
        assert all("done" in str(table.get_row_at(i)[2]) for i in range(n))

        await pilot.press("4")
        await settle(app, pilot)
        h = app.screen.health
        assert h is not None, text(app, "#summary")
        assert h.n_poses == n and h.verdict == "healthy"
        assert "HEALTHY" in text(app, "#summary")
        for name in ("measurements.csv", "journal.jsonl", "report.json", "joint_curves.png"):
            assert (station.run_dir / name).is_file(), name
        await pilot.press("5")
        await settle(app, pilot)
        d = app.screen.diagnosis
        assert d is not None and d.verdict in ("adequate", "missing-effect")
        assert app.screen.query_one("#residuals").row_count == n
        assert "model: chebyshev" in text(app, "#diag-verdict")
        await pilot.press("6")
        await settle(app, pilot)
        assert [r.run_id for r in app.screen.history.rows] == ["sim-run-1"]
    assert not station.cell.running


@pytest.mark.slow
async def test_abort_stops_the_robot_first_and_keeps_the_journal(tmp_path: Path, plan) -> None:  # type: ignore[no-untyped-def]
    station = sim_station(tmp_path, plan)
    robot = station.cell.station.robot
    events: list[str] = []
    real_stop = robot.stop

    def spy_stop() -> None:
        events.append(f"robot.stop while {station.cell.state}")
        real_stop()

    robot.stop = spy_stop  # type: ignore[method-assign]
    app = QuickhealthApp(station)
    async with app.run_test(size=(80, 24)) as pilot:
        await settle(app, pilot)
        await run_until_first_pose(app, pilot)
        # p pauses after the current pose: the arm stays still until p again
        await pilot.press("p")
        await wait_for(app, pilot, lambda: app.screen.progress.state == "paused")
        assert station.paused and "Paused" in text(app, "#run-state")
        moves = robot.n_moves
        await pilot.pause(0.5)
        assert robot.n_moves == moves
        await pilot.press("p")
        await wait_for(app, pilot, lambda: robot.n_moves > moves)
        assert app.screen.progress.state == "running"
        paused_at = app.screen.progress.done
        await wait_for(app, pilot, lambda: app.screen.progress.done > paused_at)
        await pilot.press("a")  # the stop runs in a worker: the UI loop never waits for it
        await wait_for(app, pilot, lambda: ended(app))
        await settle(app, pilot)
        assert events[0] == "robot.stop while running"  # before the run noticed anything
        assert app.screen.progress.state == "aborted"
        assert "Aborted" in text(app, "#run-state")
        # journal intact: readable, ends with the stop record, every pose at most once
        st = read_journal(station.run_dir / JOURNAL)
        assert not st.truncated_tail and st.stops and not st.ended
        done = journal_indices(station.run_dir)
        assert 2 <= len(done) < len(plan.poses) and len(done) == len(set(done))
        assert sorted(done) == list(range(1, len(done) + 1))
        # r continues the same run without repeating a pose
        await start_run(app, pilot)
        await wait_for(app, pilot, lambda: ended(app))
        await settle(app, pilot)
        assert app.screen.progress.state == "finished"
        again = journal_indices(station.run_dir)
        assert sorted(again) == list(range(1, len(plan.poses) + 1))
        kinds = [rec["type"] for _, rec, _ in iter_records(station.run_dir / JOURNAL)]
        assert kinds.count("resume") == 2 and kinds.count("stop") == 2, kinds  # pause, abort
        assert kinds[-1] == "end"


@pytest.mark.slow
async def test_connection_loss_is_shown_at_once_and_recovered(tmp_path: Path, plan) -> None:  # type: ignore[no-untyped-def]
    station = sim_station(tmp_path, plan)
    robot = station.cell.station.robot
    robot.inject("connection_drop", after_moves=3)
    app = QuickhealthApp(station)
    async with app.run_test(size=(80, 24)) as pilot:
        await settle(app, pilot)
        await pilot.press("3")
        await settle(app, pilot)
        await start_run(app, pilot)
        await wait_for(app, pilot, lambda: ended(app))
        await pilot.pause()
        p = app.screen.progress
        assert p.state == "fault" and p.fault is not None and p.fault.kind == "connection-lost"
        box = app.screen.query_one("#fault")
        assert box.display
        shown = text(app, "#fault")
        assert "Lost the connection" in shown and "What to do" in shown and "network cable" in shown
        # the station screen says so too
        await pilot.press("1")
        await settle(app, pilot)
        assert "down" in str(app.screen.query_one("#connections").get_row_at(0)[1])
        assert "NO-GO" in text(app, "#verdict")
        await pilot.press("3")
        await pilot.pause()
        # still down: c says so and the box stays
        await pilot.press("c")
        await settle(app, pilot)
        assert app.screen.query_one("#fault").display
        # the technician fixes the network; c reconnects, r continues where it stopped
        robot.release()
        await pilot.press("c")
        await settle(app, pilot)
        assert not app.screen.query_one("#fault").display
        assert "Connected again" in text(app, "#run-state")
        before = journal_indices(station.run_dir)
        await start_run(app, pilot)
        await wait_for(app, pilot, lambda: ended(app))
        await settle(app, pilot)
        assert app.screen.progress.state == "finished"
        after = journal_indices(station.run_dir)
        assert after[: len(before)] == before
        assert sorted(after) == list(range(1, len(plan.poses) + 1))


def test_a_protective_stop_is_named_with_what_to_do() -> None:
    from quickhealth.station.sim.fake_robot import FakeRobot
    from quickhealth.station.tui.cell import classify

    robot = FakeRobot()
    robot.inject("protective_stop")
    fault = classify(robot, "the move did not finish: protective stop")
    assert fault.kind == "protective-stop"
    assert "protective stop" in fault.message and "teach pendant" in fault.what_to_do
    robot.release()
    robot.inject("connection_drop")
    assert classify(robot, "lost the RTDE connection").kind == "connection-lost"


@pytest.mark.slow
async def test_station_screen_refuses_preflight_and_connect_during_a_run(
    tmp_path: Path, plan
) -> None:  # type: ignore[no-untyped-def]
    """f and c on the Facade screen would reach into the devices the run is using: while a
    run goes (here: paused between poses) both refuse, and neither touches a device."""
    station = sim_station(tmp_path, plan)
    cell = station.cell
    calls: list[str] = []
    for name in ("preflight", "connect", "connections"):
        real = getattr(cell, name)

        def spy(*a, _real=real, _name=name, **k):  # type: ignore[no-untyped-def]
            calls.append(_name)
            return _real(*a, **k)

        setattr(cell, name, spy)
    app = QuickhealthApp(station)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(app, pilot)
        await run_until_first_pose(app, pilot)
        await pilot.press("p")
        await wait_for(app, pilot, lambda: app.screen.progress.state == "paused")
        # (the run's worker waits while paused: no settle(), which waits for every worker)
        await pilot.press("1")
        await pilot.pause(0.5)
        verdict = text(app, "#verdict")
        calls.clear()
        moves = cell.station.robot.n_moves
        for key in ("f", "c"):
            await pilot.press(key)
            await pilot.pause(0.5)
        assert type(app.screen).__name__ == "StationScreen"
        assert calls == [], calls  # no pre-flight, no connect: the devices stay the run's
        assert text(app, "#verdict") == verdict
        said = [n.message for n in app._notifications]
        assert any("pre-flight waits until the run is stopped" in m for m in said), said
        assert any("Reconnecting waits until the run is stopped" in m for m in said), said
        assert station.running and cell.station.robot.n_moves == moves
        await pilot.press("3")
        await pilot.pause(0.2)
        await pilot.press("p")
        await wait_for(app, pilot, lambda: ended(app))
        await settle(app, pilot)
        assert app.screen.progress.state == "finished"


@pytest.mark.slow
async def test_r_waits_while_a_reconnect_goes(tmp_path: Path, plan) -> None:  # type: ignore[no-untyped-def]
    """The reconnect after a fault and r's pre-flight both use the robot: r during a
    reconnect is refused with a line on the screen, and works once the reconnect is done."""
    import threading

    station = sim_station(tmp_path, plan)
    robot = station.cell.station.robot
    robot.inject("connection_drop", after_moves=3)
    go_on = threading.Event()

    def slow_connect() -> None:  # the controller takes a while to answer again
        go_on.wait(20.0)
        robot.release()

    robot.connect = slow_connect  # type: ignore[attr-defined]
    app = QuickhealthApp(station)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(app, pilot)
        await pilot.press("3")
        await settle(app, pilot)
        await start_run(app, pilot)
        await wait_for(app, pilot, lambda: ended(app))
        await pilot.pause()
        assert app.screen.progress.state == "fault"
        await pilot.press("c")
        await pilot.pause(0.2)
        assert "Reconnecting" in text(app, "#run-state")
        await pilot.press("r")
        await pilot.pause(0.3)
        assert not isinstance(app.screen, ConfirmScreen)  # no pre-flight, no question
        busy = app.screen.query_one("#run-busy")
        assert busy.display and "reconnect is still going" in text(app, "#run-busy")
        go_on.set()
        await settle(app, pilot)
        assert "Connected again" in text(app, "#run-state")
        assert not app.screen.query_one("#run-busy").display
        await start_run(app, pilot)
        await wait_for(app, pilot, lambda: ended(app))
        await settle(app, pilot)
        assert app.screen.progress.state == "finished"


@pytest.mark.slow
async def test_an_abort_whose_stop_is_not_confirmed_says_so(tmp_path: Path, plan) -> None:  # type: ignore[no-untyped-def]
    """The robot could not confirm the stop (controller unreachable): the Run screen never
    says "robot stopped"; it says the stop was NOT confirmed and what to do."""
    from quickhealth.identify.errors import HardwareError

    station = sim_station(tmp_path, plan)
    robot = station.cell.station.robot
    real_stop = robot.stop

    def unconfirmed_stop() -> None:
        real_stop()  # the fake arm halts, but the controller never says so
        raise HardwareError(
            "the stop of the arm could not be confirmed (no ur-rtde client; the dashboard "
            "server cannot be reached): the arm may still be moving: press the emergency stop"
        )

    robot.stop = unconfirmed_stop  # type: ignore[method-assign]
    app = QuickhealthApp(station)
    async with app.run_test(size=(100, 30)) as pilot:
        await settle(app, pilot)
        await run_until_first_pose(app, pilot)
        await pilot.press("a")
        await wait_for(app, pilot, lambda: ended(app))
        await settle(app, pilot)
        p = app.screen.progress
        assert p.state == "aborted" and p.fault is not None and p.fault.kind == "stop-unconfirmed"
        state = text(app, "#run-state")
        assert "NOT confirmed" in state and "robot stopped" not in state
        shown = text(app, "#fault")
        assert "could not be confirmed" in shown and "emergency stop" in shown
