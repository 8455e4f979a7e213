"""Screen 6, History: this robot's runs and quick checks over time, with the trend.

Each run shows the verdict its report gave (the words of the report, ``trend`` and Results),
each quick check its own (unchanged or changed); the latest run's verdict heads the screen.
``b`` makes the selected run the robot's baseline, ``l`` reloads from the archive.
"""

from __future__ import annotations

from rich.markup import escape
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
    """Is the robot getting worse?  ``l`` reloads from the archive, ``b`` sets the baseline."""

    BINDINGS = [Binding("l", "reload", "Reload"), Binding("b", "baseline", "Set as baseline")]

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
        runs.add_columns("Run / check", "When (UTC)", "Mean mm", "Std mm", "Max mm", "Verdict")
        self.action_reload()

    def on_screen_resume(self) -> None:
        self.action_reload()

    def action_reload(self) -> None:
        self._load()

    def action_baseline(self) -> None:
        """``b``: the selected run becomes the robot's baseline (a check cannot)."""
        h = self.history
        runs = self.query_one("#runs", DataTable)
        if h is None or not h.rows or runs.cursor_row is None:
            self.notify("No run to choose: archive a run first.", severity="warning")
            return
        row = list(reversed(h.rows))[runs.cursor_row]
        if row.kind != "run":
            self.notify("A quick check cannot be a baseline: choose a run.", severity="warning")
            return
        self._set_baseline(row.run_id)

    @work(thread=True, exclusive=True, group="history-baseline")
    def _set_baseline(self, run_id: str) -> None:
        try:
            line = self.app.station.set_baseline(run_id)  # type: ignore[attr-defined]
        except Exception as exc:  # noqa: BLE001 - shown to the technician
            self.app.call_from_thread(self.notify, f"Baseline: {exc}", severity="error")
            return
        self.app.call_from_thread(self.notify, line)
        self.app.call_from_thread(self.action_reload)

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
        n_runs = sum(r.kind == "run" for r in h.rows)
        n_checks = len(h.rows) - n_runs
        head = [
            f"[b]{escape(h.robot)}[/b]: {n_runs} runs, {n_checks} quick checks · archive "
            f"{escape(h.archive)}"
        ]
        if h.latest:
            word, _, why = h.latest[0].partition(": ")
            colour = {"HEALTHY": "green", "DEGRADED": "yellow"}.get(word, "red")
            head.append(f"latest run: [b {colour}]{escape(word)}[/]: {escape(why)}")
            head += [escape(x) for x in h.latest[1:3]]
        head.append(f"trend: {escape(h.trend)}")
        self.query_one("#trend", Static).update("\n".join(head))
        runs = self.query_one("#runs", DataTable)
        runs.clear()
        colours = {"healthy": "green", "unchanged": "green", "degraded": "yellow"}
        for r in reversed(h.rows):
            colour = colours.get(r.verdict, "red" if r.verdict != "not judged" else "dim")
            verdict = f"[{colour}]{r.verdict}[/]"
            if r.kind == "check":
                name, nums = f"{r.run_id} (check)", ("–", "–", "–")
            else:
                name = r.run_id + (" ★ baseline" if r.baseline else "")
                nums = (f"{r.mean_mm:.3f}", f"{r.std_mm:.3f}", f"{r.max_mm:.3f}")
            runs.add_row(name, r.when, *nums, verdict)
        widget = self.query_one("#trend-plot", PlotextPlot)
        plt = widget.plt
        plt.clear_data()
        plt.clear_figure()
        rows = [r for r in h.rows if r.kind == "run"]
        if rows:
            x = list(range(1, len(rows) + 1))
            plt.plot(x, [r.mean_mm for r in rows], label="mean", marker="braille", color="cyan")
            plt.plot(x, [r.max_mm for r in rows], label="max", marker="braille", color="red")
            plt.xlabel("run")
            plt.title("workspace error (mm) over runs")
        widget.refresh()
