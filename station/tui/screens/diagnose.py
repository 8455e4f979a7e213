"""Screen 5, Diagnose: where the model fails, which effect is missing, add it, watch the error fall.

``d`` diagnoses the current model; ``s`` sorts the per-pose table (worst first, then by pose);
arrow keys pick a candidate effect in the lower table and ``a`` adds it: the model is refitted
in the background with progress, and the held-out error before and after appear side by side.
"""

from __future__ import annotations

from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import DataTable, Footer, ProgressBar, Static

from ..views import Diagnosis, Refit
from ..widgets.nav import NavBar

SORTS = ("err", "pose")


class DiagnoseScreen(Screen[None]):
    """Compare model and measurements, and close the gap."""

    BINDINGS = [
        Binding("d", "diagnose", "Diagnose"),
        Binding("s", "sort", "Sort"),
        Binding("a", "add_effect", "Add effect"),
        Binding("tab", "focus_next", "Next table", show=False),
    ]

    diagnosis: reactive[Diagnosis | None] = reactive(None)
    refit: reactive[Refit | None] = reactive(None)
    sort_by = reactive(0)

    def compose(self) -> ComposeResult:
        yield NavBar("diagnose")
        with Vertical(id="diag-body"):
            with Horizontal(id="diag-top"):
                yield DataTable(id="residuals", cursor_type="row", zebra_stripes=True)
                with Vertical(id="diag-side"):
                    yield Static(
                        "Press [b]d[/b] to diagnose the model.", id="diag-verdict", classes="panel"
                    )
                    yield Static("", id="before-after", classes="panel")
                    yield ProgressBar(id="refit-bar", show_eta=False)
            with Horizontal(id="diag-bottom"):
                yield DataTable(id="candidates", cursor_type="row")
                yield Static("", id="evidence", classes="panel")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        res = self.query_one("#residuals", DataTable)
        res.add_column("Pose", key="pose")
        res.add_column("err mm", key="err")
        res.add_column("model−meas x y z mm (base)", key="diff")
        res.add_column("measured x y z mm (base)", key="meas")
        cand = self.query_one("#candidates", DataTable)
        cand.add_column("#", key="rank")
        cand.add_column("Effect", key="effect")
        cand.add_column("Score", key="score")
        cand.add_column("−RMS mm", key="drop")
        self.query_one("#refit-bar").display = False

    def on_screen_resume(self) -> None:
        if self.diagnosis is None and self.app.station.has_measurements():  # type: ignore[attr-defined]
            self.action_diagnose()

    def action_diagnose(self) -> None:
        if not self.app.station.has_measurements():  # type: ignore[attr-defined]
            self.notify("No measurements yet: run the plan first (3, r).", severity="warning")
            return
        self.query_one("#diag-verdict", Static).update("Diagnosing… (fit, then residual tests)")
        self._diagnose()

    @work(thread=True, exclusive=True, group="diagnose")
    def _diagnose(self) -> None:
        try:
            d = self.app.station.diagnose()  # type: ignore[attr-defined]
        except Exception as exc:
            self.app.call_from_thread(
                self.query_one("#diag-verdict", Static).update, f"[red]Diagnosis failed: {exc}[/]"
            )
            return
        self.app.call_from_thread(self.set_diagnosis, d)

    def set_diagnosis(self, d: Diagnosis) -> None:
        self.diagnosis = d

    def watch_diagnosis(self, d: Diagnosis | None) -> None:
        if d is None:
            return
        model = "chebyshev" + "".join(f" + {e}" for e in d.effects)
        if d.verdict == "adequate":
            head = "[b green]Model adequate[/]: no missing effect is significant."
        else:
            head = "[b yellow]Missing effect[/]: pick one below, press [b]a[/b]."
        self.query_one("#diag-verdict", Static).update(f"{head}\nmodel: {model}")
        self._fill_residuals()
        cand = self.query_one("#candidates", DataTable)
        cand.clear()
        for i, c in enumerate(d.candidates):
            cand.add_row(
                str(i + 1),
                c.effect,
                f"{c.score:.1f}",
                f"{c.predicted_rms_drop_mm:.3f}",
                key=c.effect,
            )
        if d.candidates:
            cand.focus()
        self._show_evidence()

    def on_data_table_row_highlighted(self, event: DataTable.RowHighlighted) -> None:
        if event.data_table.id == "candidates":
            self._show_evidence()

    def _show_evidence(self) -> None:
        d = self.diagnosis
        effect = self.chosen_effect()
        if d is None or effect is None:
            self.query_one("#evidence", Static).update("")
            return
        c = next(c for c in d.candidates if c.effect == effect)
        self.query_one("#evidence", Static).update(
            f"[b]{c.effect}[/b]: {c.evidence}\n[dim]a adds it and refits[/]"
        )

    def _fill_residuals(self) -> None:
        d = self.diagnosis
        if d is None:
            return
        rows = list(d.residuals)
        if SORTS[self.sort_by] == "err":
            rows.sort(key=lambda r: -r.err_mm)
        res = self.query_one("#residuals", DataTable)
        res.clear()
        for r in rows:
            diff = tuple(m - s for m, s in zip(r.model_mm, r.measured_mm, strict=True))
            res.add_row(
                r.pose_id,
                f"{r.err_mm:.3f}",
                " ".join(f"{v:+.3f}" for v in diff),
                " ".join(f"{v:7.1f}" for v in r.measured_mm),
                key=r.pose_id,
            )

    def action_sort(self) -> None:
        self.sort_by = (self.sort_by + 1) % len(SORTS)

    def watch_sort_by(self) -> None:
        self._fill_residuals()
        if self.diagnosis is not None:
            self.notify("sorted worst first" if SORTS[self.sort_by] == "err" else "sorted by pose")

    def on_data_table_header_selected(self, event: DataTable.HeaderSelected) -> None:
        if event.data_table.id == "residuals":
            self.sort_by = 0 if event.column_key.value == "err" else 1

    def chosen_effect(self) -> str | None:
        d = self.diagnosis
        if d is None or not d.candidates:
            return None
        cand = self.query_one("#candidates", DataTable)
        row = min(max(cand.cursor_row, 0), len(d.candidates) - 1)
        return d.candidates[row].effect

    def action_add_effect(self) -> None:
        effect = self.chosen_effect()
        if effect is None:
            self.notify("No candidate to add: diagnose first (d).", severity="warning")
            return
        bar = self.query_one("#refit-bar", ProgressBar)
        bar.update(total=3, progress=0)
        bar.display = True
        self.query_one("#before-after", Static).update(f"Refitting with [b]{effect}[/b]…")
        self._refit(effect)

    @work(thread=True, exclusive=True, group="refit")
    def _refit(self, effect: str) -> None:
        def on_step(done: int, total: int, what: str) -> None:
            self.app.call_from_thread(self._refit_step, done, total, what)

        try:
            r = self.app.station.add_effect(effect, on_step)  # type: ignore[attr-defined]
        except Exception as exc:
            self.app.call_from_thread(
                self.query_one("#before-after", Static).update, f"[red]Refit failed: {exc}[/]"
            )
            return
        self.app.call_from_thread(self.set_refit, r)

    def _refit_step(self, done: int, total: int, what: str) -> None:
        self.query_one("#refit-bar", ProgressBar).update(total=total, progress=done)
        self.query_one("#before-after", Static).update(what)

    def set_refit(self, r: Refit) -> None:
        self.refit = r
        self.query_one("#refit-bar").display = False
        self.action_diagnose()

    def watch_refit(self, r: Refit | None) -> None:
        if r is None:
            return
        better = r.after_mm < r.before_mm
        color = "green" if better else "red"
        ax = "xyz"
        lines = [
            f"[b]Held-out error[/b] ({r.heldout})",
            f"{'':6}{'before':>9}{'after':>9}",
            f"{'rms':6}{r.before_mm:9.3f}[{color}]{r.after_mm:9.3f}[/] mm",
        ]
        for i in range(3):
            lines.append(f"{ax[i]:6}{r.before_axes_mm[i]:9.3f}{r.after_axes_mm[i]:9.3f}")
        lines.append(
            f"[{color}]{'−' if better else '+'}{abs(r.drop_fraction):.0%}[/] with {r.effects_after[-1]}"
        )
        self.query_one("#before-after", Static).update("\n".join(lines))
