"""The TUI on the simulated cell with the real drivers: the ur-rtde client (in its own process)
against the UR controller simulator (another process), the serial driver against the pan-motor
emulator, rendered cameras.  The whole planned loop with an abort, a controller restart, two
reconnects and two continues in the middle; at the end the journal holds every pose once.
"""

from __future__ import annotations

import time

import pytest
from qh_tui import ended, journal_indices, settle, start_run, text, wait_for

from quickhealth.station.run.journal import JOURNAL, iter_records, read_journal
from quickhealth.station.tui.app import QuickhealthApp
from quickhealth.station.tui.simulated import open_simulated

pytestmark = [pytest.mark.slow, pytest.mark.timeout(280)]


async def reconnect(app: QuickhealthApp, pilot, timeout: float = 30.0) -> int:  # type: ignore[no-untyped-def]
    """Press c until the robot is back (the controller may still be booting); tries needed."""
    t0 = time.monotonic()
    tries = 0
    while True:
        tries += 1
        await pilot.press("c")
        await settle(app, pilot)
        if "Connected again" in text(app, "#run-state"):
            return tries
        assert time.monotonic() - t0 < timeout, text(app, "#run-state")
        await pilot.pause(0.5)


async def test_whole_loop_with_abort_restart_reconnect_and_continue(tmp_path) -> None:  # type: ignore[no-untyped-def]
    station = open_simulated(
        cell="reference",
        archive=tmp_path / "archive",
        n_poses=20,
        run_id="pilot",
        speed_factor=10.0,
        image_scale=0.25,
    )
    n = len(station.plan.poses)
    assert n >= 8, n
    sim = station.simcell.controller
    app = QuickhealthApp(station)
    try:
        async with app.run_test(size=(100, 30)) as pilot:
            await settle(app, pilot)
            await pilot.press("3")
            await settle(app, pilot)
            await start_run(app, pilot)
            await wait_for(app, pilot, lambda: app.screen.progress.done >= 2, timeout=90)

            # 1. abort mid-run: the arm stops, the run ends, nothing measured is lost
            await pilot.press("a")
            await wait_for(app, pilot, lambda: ended(app))
            await settle(app, pilot)
            assert app.screen.progress.state == "aborted"
            assert not sim.state()["moving"]
            aborted_at = journal_indices(station.run_dir)
            await reconnect(app, pilot)
            await start_run(app, pilot)
            await wait_for(
                app, pilot, lambda: app.screen.progress.done >= len(aborted_at) + 2, timeout=90
            )

            # 2. the controller restarts mid-run: every connection drops, new ones are refused
            # for a second, the program stops and the registers are reset
            restarts = sim.state()["n_restarts"]
            sim.fault("restart", down_s=1.0)
            await wait_for(app, pilot, lambda: ended(app))
            await settle(app, pilot)
            p = app.screen.progress
            assert p.state == "fault" and p.fault is not None, p
            assert p.fault.kind in ("connection-lost", "frozen-stream"), p.fault
            assert app.screen.query_one("#fault").display
            await reconnect(app, pilot)
            st = sim.state()  # a restarted controller, its program uploaded and running again
            assert st["n_restarts"] == restarts + 1 and st["accepting"], st
            assert st["runtime_state"] == 2, st
            await start_run(app, pilot)
            await wait_for(app, pilot, lambda: ended(app), timeout=150)
            await settle(app, pilot)
            assert app.screen.progress.state == "finished", app.screen.progress
    finally:
        station.cell.close()
    # The journal is complete: every pose exactly once, in plan order, and the run ended.
    done = journal_indices(station.run_dir)
    assert sorted(done) == list(range(1, n + 1)) and len(done) == len(set(done))
    st = read_journal(station.run_dir / JOURNAL)
    assert st.ended and not st.truncated_tail
    kinds = [rec["type"] for _, rec, _ in iter_records(station.run_dir / JOURNAL)]
    assert kinds.count("stop") == 2 and kinds.count("resume") == 2 and kinds[-1] == "end", kinds
    rows = (station.run_dir / "measurements.csv").read_text().splitlines()
    assert sum(1 for r in rows if r and not r.startswith("#")) - 1 == len(st.measured)
