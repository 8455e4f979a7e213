"""Screen 3, Run: progress with ETA, current pose, last measurement, per-pose table, control.

``r`` starts (after pre-flight and a yes in the motion dialog), ``p`` pauses and resumes,
``a`` aborts (the facade stops the robot before anything else), ``c`` reconnects after a
lost connection or protective stop and continues the run where it stopped.  ``k`` runs the
quick check against the robot's archived baseline (after a yes in the motion dialog): a few
poses, "unchanged" or "changed", recorded in the archive as a check.
"""

from __future__ import annotations

from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import DataTable, Footer, ProgressBar, Static

from ..views import CellState, PoseStatus, RunProgress
from ..widgets.nav import NavBar
from ..widgets.textplot import fmt_duration
from .confirm import ConfirmScreen

STATUS_MARK = {
    "pending": "[dim]·[/]",
    "moving": "[cyan]moving[/]",
    "measuring": "[cyan]measuring[/]",
    "done": "[green]✓ done[/]",
    "failed": "[red]✗ failed[/]",
    "skipped": "[yellow]skipped[/]",
}
# an abort whose stop the controller did not confirm (display only: the state is ABORTED)
ABORTED_UNCONFIRMED_WORDS = (
    "[b red]Aborted, but the stop was NOT confirmed[/]: the arm may still be moving (below)."
)
STATE_WORDS = {
    CellState.IDLE: "Ready: press [b]r[/b] to start the run.",
    CellState.RUNNING: "[cyan]Running[/]  [b]p[/b] pause · [b]a[/b] abort",
    CellState.PAUSED: "[yellow]Paused[/] after this pose  [b]p[/b] resume · [b]a[/b] abort",
    CellState.ABORTED: "[red]Aborted[/]: robot stopped, measured poses kept. [b]r[/b] resumes the run.",
    CellState.FAULT: "[b red]Stopped by a fault[/] (below)",
    CellState.FINISHED: "[green]Finished[/]: press [b]4[/b] for the results.",
}


def _pose_cells(ps: PoseStatus) -> tuple[str, str, str, str]:
    markers = "–" if ps.markers is None else str(ps.markers)
    reproj = "–" if ps.reproj_px is None else f"{ps.reproj_px:.2f}"
    return STATUS_MARK.get(ps.status, ps.status), markers, reproj, ps.reason


class RunScreen(Screen[None]):
    """Run the frozen plan on the station and watch every pose."""

    BINDINGS = [
        Binding("r", "start", "Run"),
        Binding("p", "pause", "Pause/resume"),
        Binding("a", "abort", "Abort"),
        Binding("c", "reconnect", "Reconnect"),
        Binding("k", "quick_check", "Quick check"),
    ]

    progress: reactive[RunProgress | None] = reactive(None)
    # What the screen's own worker is doing with the station now ("reconnect", "pre-flight")
    # or None: r and c refuse while the other runs, so the two never go at once.
    busy: str | None = None

    def compose(self) -> ComposeResult:
        yield NavBar("run")
        with Vertical(id="run-body"):
            with Horizontal(id="run-top"):
                yield ProgressBar(id="run-bar", show_eta=False)
                yield Static("", id="run-eta")
            yield Static(STATE_WORDS[CellState.IDLE], id="run-state")
            yield Static("", id="run-busy")
            yield Static("", id="fault", classes="fault")
            yield Static("Current pose: –", id="run-current")
            yield Static("Last measurement: –", id="run-last")
            yield DataTable(id="poses", cursor_type="row", zebra_stripes=True)
        yield Footer(compact=True)

    def on_mount(self) -> None:
        table = self.query_one("#poses", DataTable)
        table.add_column("#", key="n")
        table.add_column("Pose", key="pose")
        table.add_column("Status", key="status")
        table.add_column("Markers", key="markers")
        table.add_column("Reproj px", key="reproj")
        table.add_column("Note", key="note")
        self.query_one("#fault").display = False
        self.query_one("#run-busy").display = False
        self._fill_table()

    def _fill_table(self) -> None:
        table = self.query_one("#poses", DataTable)
        table.clear()
        rows = self.app.station.pose_table()  # type: ignore[attr-defined]
        for ps in rows:
            table.add_row(str(ps.index + 1), ps.pose_id, *_pose_cells(ps), key=str(ps.index))
        done = sum(ps.status in ("done", "failed") for ps in rows)
        self.query_one("#run-bar", ProgressBar).update(total=max(1, len(rows)), progress=done)
        self.query_one("#run-eta", Static).update(f"{done}/{len(rows)}")
        if not self.app.station.can_run:  # type: ignore[attr-defined]
            self.query_one("#run-state", Static).update(
                f"Measured data, no station attached: {done} poses."
            )

    # ----- control ---------------------------------------------------------------------------
    def action_start(self) -> None:
        """Pre-flight, then ask before the arm moves, then run in a worker."""
        station = self.app.station  # type: ignore[attr-defined]
        if not station.can_run:
            self.notify("No station attached: start with --sim or --robot-ip.", severity="error")
            return
        if station.running:
            self.notify("The run is already going.", severity="warning")
            return
        if self._refuse_while_busy("The run"):
            return
        self.busy = "pre-flight"
        self._preflight_then_ask()

    def _refuse_while_busy(self, what: str) -> bool:
        if self.busy is None:
            return False
        line = f"{what} waits: the {self.busy} is still going."
        busy_line = self.query_one("#run-busy", Static)
        busy_line.update(f"[yellow]{line}[/]")
        busy_line.display = True
        self.notify(line, severity="warning")
        return True

    def _idle(self) -> None:
        self.busy = None
        self.query_one("#run-busy", Static).display = False

    @work(thread=True, exclusive=True, group="run-preflight")
    def _preflight_then_ask(self) -> None:
        try:
            pf = self.app.station.preflight()  # type: ignore[attr-defined]
        finally:
            self.app.call_from_thread(self._idle)
        self.app.call_from_thread(self._ask, pf)

    def _ask(self, pf) -> None:  # type: ignore[no-untyped-def]
        if not pf.go:
            self.notify("NO-GO: " + "; ".join(pf.reasons), severity="error", timeout=8)
            return
        n = self.app.station.n_remaining()  # type: ignore[attr-defined]
        question = (
            f"The arm will move through {n} poses.\nIs the cell clear and the e-stop in reach?"
        )

        def answer(yes: bool | None) -> None:
            if yes:
                self._run()

        self.app.push_screen(ConfirmScreen(question), answer)

    @work(thread=True, exclusive=True, group="run")
    def _run(self) -> None:
        def on_progress(p: RunProgress) -> None:
            self.app.call_from_thread(self.set_progress, p)

        final = self.app.station.run(on_progress)  # type: ignore[attr-defined]
        self.app.call_from_thread(self.set_progress, final)

    def action_quick_check(self) -> None:
        """Ask before the arm moves, then the quick check in a worker."""
        station = self.app.station  # type: ignore[attr-defined]
        if not station.can_run:
            self.notify("No station attached: start with --sim or --robot-ip.", severity="error")
            return
        if station.running or self._refuse_while_busy("The quick check"):
            self.notify("The devices are busy: wait for the run to end.", severity="warning")
            return
        question = (
            "Quick check against this robot's baseline: the arm moves through a few poses "
            "of the plan.\nIs the cell clear and the e-stop in reach?"
        )

        def answer(yes: bool | None) -> None:
            if yes:
                self.busy = "quick check"
                self.query_one("#run-state", Static).update("[cyan]Quick check[/]  [b]a[/b] abort")
                self._quick_check()

        self.app.push_screen(ConfirmScreen(question), answer)

    def _check_step(self, done: int, total: int, text: str) -> None:
        """The check's own progress: its poses measured so far (it stops as soon as it can
        decide, at most the plan's poses)."""
        self.query_one("#run-bar", ProgressBar).update(total=max(1, total), progress=done)
        self.query_one("#run-eta", Static).update(f"check: {done} poses measured (≤ {total})")
        self.query_one("#run-current", Static).update(f"Quick check: {text}")

    @work(thread=True, exclusive=True, group="run")
    def _quick_check(self) -> None:
        def step(done: int, total: int, text: str) -> None:
            self.app.call_from_thread(self._check_step, done, total, text)

        try:
            lines = self.app.station.quick_check(step)  # type: ignore[attr-defined]
        except Exception as exc:  # noqa: BLE001 - shown to the technician
            self.app.call_from_thread(self.notify, f"Quick check: {exc}", severity="error")
            self.app.call_from_thread(
                self.query_one("#run-state", Static).update, f"[red]Quick check stopped[/]: {exc}"
            )
            return
        finally:
            self.app.call_from_thread(self._idle)
        head = lines[0]
        colour = "red" if head.startswith("CHANGED") else "green"
        text = f"[b {colour}]{head}[/]" + "".join(f"\n{x}" for x in lines[1:])
        self.app.call_from_thread(self.query_one("#run-state", Static).update, text)
        self.app.call_from_thread(
            self.notify, head, severity="warning" if colour == "red" else "information"
        )

    def action_pause(self) -> None:
        station = self.app.station  # type: ignore[attr-defined]
        if not station.running:
            return
        if station.paused:
            station.resume()
            self.notify("Resumed.")
        else:
            station.pause()
            self.notify("Pausing after the current pose…")

    def action_abort(self) -> None:
        """Stop the robot first, then end the run (what was measured stays in the journal)."""
        station = self.app.station  # type: ignore[attr-defined]
        if not station.running:
            return
        self.query_one("#run-state", Static).update("[red]Aborting[/]: stopping the robot…")
        self._abort()

    @work(thread=True, exclusive=True, group="run-abort")
    def _abort(self) -> None:
        """The stop waits for the controller's answer (up to a second): never on the UI loop."""
        try:
            self.app.station.abort()  # type: ignore[attr-defined]
        except Exception as exc:  # noqa: BLE001 - shown to the technician
            self.app.call_from_thread(
                self.notify,
                f"Abort: the stop was NOT confirmed: {exc}",
                severity="error",
                timeout=30,
            )
            self.app.call_from_thread(
                self.query_one("#run-state", Static).update, ABORTED_UNCONFIRMED_WORDS
            )
            return
        self.app.call_from_thread(self.notify, "Abort: robot stopped.", severity="warning")

    def action_reconnect(self) -> None:
        p = self.progress
        if p is None or p.state not in (CellState.FAULT, CellState.ABORTED):
            self.notify("Nothing to reconnect: the run is not stopped by a fault.")
            return
        if self._refuse_while_busy("Reconnecting"):
            return
        self.busy = "reconnect"
        self.query_one("#run-state", Static).update("Reconnecting…")
        self._reconnect()

    @work(thread=True, exclusive=True, group="run-reconnect")
    def _reconnect(self) -> None:
        try:
            self.app.station.reconnect()  # type: ignore[attr-defined]
        except Exception as exc:
            self.app.call_from_thread(self.notify, f"Still no connection: {exc}", severity="error")
            self.app.call_from_thread(
                self.query_one("#run-state", Static).update, STATE_WORDS[CellState.FAULT]
            )
            return
        finally:
            self.app.call_from_thread(self._idle)
        self.app.call_from_thread(self._reconnected)

    def _reconnected(self) -> None:
        self.query_one("#fault").display = False
        self.notify("Connection back. Press r to continue the run where it stopped.")
        self.query_one("#run-state", Static).update(
            "[green]Connected again[/]: press [b]r[/b] to continue where the run stopped."
        )

    # ----- display ---------------------------------------------------------------------------
    def set_progress(self, p: RunProgress) -> None:
        self.progress = p

    def watch_progress(self, p: RunProgress | None) -> None:
        if p is None:
            return
        bar = self.query_one("#run-bar", ProgressBar)
        bar.update(total=max(1, p.total), progress=p.done)
        eta = "" if p.state != CellState.RUNNING else f"ETA {fmt_duration(p.eta_s)}"
        self.query_one("#run-eta", Static).update(f"{p.done}/{p.total}  {eta}")
        words = STATE_WORDS.get(p.state, p.state)
        if p.state == CellState.ABORTED and p.fault is not None:
            words = ABORTED_UNCONFIRMED_WORDS
        self.query_one("#run-state", Static).update(words)
        fault = self.query_one("#fault", Static)
        if p.fault is not None:
            fault.update(
                f"[b]{p.fault.message}[/b]\nWhat to do: {p.fault.what_to_do}\n"
                "Then press [b]c[/b] to reconnect and [b]r[/b] to continue."
            )
            fault.display = True
        else:
            fault.display = False
        if p.current is None and p.state != CellState.RUNNING:
            self.query_one("#run-current", Static).update("Current pose: –")
            for ps in self.app.station.pose_table():  # type: ignore[attr-defined]
                if ps.status == "pending":
                    self._update_row(ps)
        if p.current is not None:
            c = p.current
            q = " ".join(f"{v:+7.1f}" for v in c.q_deg)
            self.query_one("#run-current", Static).update(
                f"Current pose {c.index + 1}/{p.total} [b]{c.pose_id}[/b] {c.status}  q° {q}"
            )
            self._update_row(c)
        if p.last_measured is not None:
            m = p.last_measured
            quality = "[green]good[/]" if m.status == "done" else f"[red]{m.reason or 'failed'}[/]"
            markers = "–" if m.markers is None else m.markers
            reproj = "–" if m.reproj_px is None else f"{m.reproj_px:.2f} px"
            self.query_one("#run-last", Static).update(
                f"Last measurement [b]{m.pose_id}[/b]: markers {markers}, reprojection {reproj}, {quality}"
            )
            self._update_row(m)

    def _update_row(self, ps: PoseStatus) -> None:
        table = self.query_one("#poses", DataTable)
        key = str(ps.index)
        if key not in table.rows:
            return
        for col, val in zip(("status", "markers", "reproj", "note"), _pose_cells(ps), strict=True):
            table.update_cell(key, col, val)
        if ps.status in ("moving", "measuring"):
            table.move_cursor(row=table.get_row_index(key), animate=False)
