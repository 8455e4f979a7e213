"""Helpers of the TUI pilot tests: wait for workers, read widgets, start a run, read the journal."""

from __future__ import annotations

import time
from pathlib import Path

from textual.widgets import Static

from quickhealth.station.run.journal import JOURNAL, iter_records
from quickhealth.station.tui.app import QuickhealthApp
from quickhealth.station.tui.screens.confirm import ConfirmScreen


async def settle(app: QuickhealthApp, pilot) -> None:  # type: ignore[no-untyped-def]
    for _ in range(3):
        await pilot.pause()
        await app.workers.wait_for_complete()
    await pilot.pause()


def text(app: QuickhealthApp, selector: str) -> str:
    return str(app.screen.query_one(selector, Static).render())


async def start_run(app: QuickhealthApp, pilot) -> None:  # type: ignore[no-untyped-def]
    """``r`` on the Run screen: pre-flight, then the motion question answered yes."""
    await pilot.press("r")
    t0 = time.monotonic()  # pre-flight renders and measures a frame: slow on a loaded machine
    while time.monotonic() - t0 < 30.0:
        await pilot.pause(0.05)
        if isinstance(app.screen, ConfirmScreen):
            break
    shown = [str(w.render()) for w in app.screen.query(Static)][:6]
    assert isinstance(app.screen, ConfirmScreen), f"no question before the arm moves: {shown}"
    await pilot.press("y")
    await pilot.pause()


async def run_until_first_pose(app: QuickhealthApp, pilot) -> None:  # type: ignore[no-untyped-def]
    """From any screen: open the Run screen (``3``), start the run and wait until one pose is done."""
    await pilot.press("3")
    await settle(app, pilot)
    await start_run(app, pilot)
    await wait_for(
        app, pilot, lambda: app.screen.progress is not None and app.screen.progress.done >= 1
    )


async def wait_for(app: QuickhealthApp, pilot, cond, timeout: float = 60.0) -> None:  # type: ignore[no-untyped-def]
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout, "timed out"
        await pilot.pause(0.1)


def ended(app: QuickhealthApp) -> bool:
    p = getattr(app.screen, "progress", None)
    return p is not None and p.state in ("finished", "aborted", "fault")


def journal_indices(run_dir: Path) -> list[int]:
    """Plan indices of every pose record in the journal, in order (captured or failed)."""
    return [
        rec["index"]
        for _, rec, _ in iter_records(run_dir / JOURNAL)
        if rec.get("type") in ("captured", "failed")
    ]
