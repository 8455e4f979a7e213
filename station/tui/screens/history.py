"""Screen 6, History: this robot's runs over time, with the trend of the main figures."""

from __future__ import annotations

from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Static
from textual_plotext import PlotextPlot

from ..views import History
from ..widgets.nav import NavBar


class HistoryScreen(Screen[None]):
    """Is the robot getting worse?  ``l`` reloads from the archive."""

    BINDINGS = [Binding("l", "reload", "Reload")]

    history: reactive[History | None] = reactive(None)

    def compose(self) -> ComposeResult:
        yield NavBar("history")
        with Vertical(id="history-body"):
            yield Static("Loading the archive…", id="trend", classes="panel")
            yield PlotextPlot(id="trend-plot")
            yield DataTable(id="runs", cursor_type="row", zebra_stripes=True)
        yield Footer(compact=True)

    def on_mount(self) -> None:
        runs = self.query_one("#runs", DataTable)
        runs.add_columns("Run", "When", "Mean mm", "Std mm", "Max mm", "Verdict")
        self.action_reload()

    def on_screen_resume(self) -> None:
        self.action_reload()

    def action_reload(self) -> None:
        self._load()

    @work(thread=True, exclusive=True, group="history")
    def _load(self) -> None:
        try:
            h = self.app.station.history()  # type: ignore[attr-defined]
        except Exception as exc:
            self.app.call_from_thread(self.query_one("#trend", Static).update, f"[red]{exc}[/]")
            return
        self.app.call_from_thread(self.set_history, h)

    def set_history(self, h: History) -> None:
        self.history = h

    def watch_history(self, h: History | None) -> None:
        if h is None:
            return
        flag = "[b red]FLAGGED[/] " if h.flagged else ""
        checks = "".join(f"\n{line}" for line in h.checks[-3:])
        self.query_one("#trend", Static).update(
            f"[b]{h.robot}[/b]: {len(h.rows)} runs · {flag}{h.trend}{checks}"
        )
        runs = self.query_one("#runs", DataTable)
        runs.clear()
        for r in reversed(h.rows):
            verdict = "[green]healthy[/]" if r.verdict == "healthy" else f"[red]{r.verdict}[/]"
            name = r.run_id + (" ★" if r.baseline else "")
            runs.add_row(
                name, r.when, f"{r.mean_mm:.3f}", f"{r.std_mm:.3f}", f"{r.max_mm:.3f}", verdict
            )
        widget = self.query_one("#trend-plot", PlotextPlot)
        plt = widget.plt
        plt.clear_data()
        plt.clear_figure()
        if h.rows:
            x = list(range(1, len(h.rows) + 1))
            plt.plot(x, [r.mean_mm for r in h.rows], label="mean", marker="braille", color="cyan")
            plt.plot(x, [r.max_mm for r in h.rows], label="max", marker="braille", color="red")
            plt.xlabel("run")
            plt.title("workspace error (mm) over runs")
        widget.refresh()
