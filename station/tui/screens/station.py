"""Screen 1, Station: connections and their state, the cell and plan, pre-flight go / no-go."""

from __future__ import annotations

from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Static

from ..views import Connection, Preflight
from ..widgets.nav import NavBar

STATE_MARK = {"ok": "[green]● ok[/]", "warn": "[yellow]● wait[/]", "down": "[red]● down[/]"}


class StationScreen(Screen[None]):
    """Is the station ready to measure?  ``c`` (re)connects, ``f`` runs the pre-flight."""

    BINDINGS = [
        Binding("c", "connect", "Connect"),
        Binding("f", "preflight", "Pre-flight"),
    ]

    preflight: reactive[Preflight | None] = reactive(None)

    def compose(self) -> ComposeResult:
        yield NavBar("station")
        with Vertical(id="station-body"):
            yield Static("", id="cell-line", classes="info")
            yield DataTable(id="connections", cursor_type="none", zebra_stripes=True)
            yield Static("Pre-flight not run yet: press [b]f[/b].", id="verdict", classes="verdict")
            yield DataTable(id="checks", cursor_type="none")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        conns = self.query_one("#connections", DataTable)
        conns.add_columns("Device", "State", "Detail")
        checks = self.query_one("#checks", DataTable)
        checks.add_columns("Check", "", "Why")
        self.query_one("#cell-line", Static).update(self.app.station.cell_line())  # type: ignore[attr-defined]
        self.action_connect()

    def on_screen_resume(self) -> None:
        """Coming back to this screen: show the devices as they are now."""
        if not self.app.station.running:  # type: ignore[attr-defined]
            self.action_preflight()

    def _refuse_during_run(self, what: str) -> bool:
        if self.app.station.running:  # type: ignore[attr-defined]
            self.notify(f"{what} waits until the run is stopped (Run screen: p or a).")
            return True
        return False

    def action_connect(self) -> None:
        """Connect (or reconnect) every device, then show their state."""
        if self._refuse_during_run("Reconnecting"):
            return
        self.query_one("#verdict", Static).update("Connecting…")
        self._connect()

    def action_preflight(self) -> None:
        """Run the pre-flight checks in the background."""
        if self._refuse_during_run("The pre-flight"):
            return
        self.query_one("#verdict", Static).update("Pre-flight running…")
        self._preflight()

    @work(thread=True, exclusive=True, group="station")
    def _connect(self) -> None:
        conns = self.app.station.connect()  # type: ignore[attr-defined]
        self.app.call_from_thread(self.show_connections, conns)
        pf = self.app.station.preflight()  # type: ignore[attr-defined]
        self.app.call_from_thread(self.set_preflight, pf)

    @work(thread=True, exclusive=True, group="station")
    def _preflight(self) -> None:
        conns = self.app.station.connections()  # type: ignore[attr-defined]
        self.app.call_from_thread(self.show_connections, conns)
        pf = self.app.station.preflight()  # type: ignore[attr-defined]
        self.app.call_from_thread(self.set_preflight, pf)

    def show_connections(self, conns: tuple[Connection, ...]) -> None:
        table = self.query_one("#connections", DataTable)
        table.clear()
        for c in conns:
            table.add_row(c.name, STATE_MARK.get(c.state, c.state), c.detail)

    def set_preflight(self, pf: Preflight) -> None:
        self.preflight = pf

    def watch_preflight(self, pf: Preflight | None) -> None:
        if pf is None:
            return
        verdict = self.query_one("#verdict", Static)
        if pf.go:
            verdict.update(
                "[b green]GO[/]  every check passed: press [b]3[/b], then [b]r[/b] to run."
            )
            verdict.set_classes("verdict go")
        else:
            n = len(pf.reasons)
            verdict.update(
                f"[b red]NO-GO[/]  {n} check{'s' if n > 1 else ''} failed: fix, then press [b]f[/b]."
            )
            verdict.set_classes("verdict nogo")
        table = self.query_one("#checks", DataTable)
        table.clear()
        for c in pf.checks:
            table.add_row(c.name, "[green]✓[/]" if c.ok else "[red]✗[/]", c.why)
