"""Screen 4, Results: workspace error, change against baseline, verdict, joint curves, worst regions.

The verdict comes first, in the words every door shows (the report, ``trend``, History):
against the accuracy spec, against the baseline, what to do.  ``j`` / ``J`` step through the
joints, ``m`` through the six error motions of the curve plot; ``f`` fits the last run (in
the background) when it has not been fitted yet; ``b`` makes this run the robot's baseline.
"""

from __future__ import annotations

import numpy as np
from rich.markup import escape
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import Footer, Static
from textual_plotext import PlotextPlot

from ....identify.errormodel import MOTIONS
from ...reporting.verdict import HealthVerdict
from ..views import Health
from ..widgets.nav import NavBar
from ..widgets.textplot import spark


def _ticks(lo: np.ndarray, hi: np.ndarray, n: int = 5) -> tuple[list[float], list[str]]:
    """Five y ticks over the band with labels of our own: a value that rounds to zero is
    "0.000", never "-0.000" (plotext prints the sign of a -1e-17 from the fit's arithmetic)."""
    a, b = float(np.min(lo)), float(np.max(hi))
    if not b > a:
        a, b = a - 1.0, b + 1.0
    ticks = np.linspace(a, b, n).tolist()
    return ticks, [f"{v:.3f}" if abs(v) >= 5e-4 else "0.000" for v in ticks]


class ResultsScreen(Screen[None]):
    """How healthy is the robot, and where is it worst?"""

    BINDINGS = [
        Binding("f", "fit", "Fit run"),
        Binding("j", "joint(1)", "Next joint"),
        Binding("J", "joint(-1)", "Prev joint", show=False),
        Binding("m", "motion", "Motion"),
        Binding("b", "baseline", "Set as baseline"),
    ]

    health: reactive[Health | None] = reactive(None)
    joint = reactive(0)
    motion = reactive(5)

    def compose(self) -> ComposeResult:
        yield NavBar("results")
        with Horizontal(id="results-body"):
            with Vertical(id="results-left"):
                yield Static(
                    "No results yet: finish a run, then press [b]f[/b].",
                    id="summary",
                    classes="panel",
                )
                yield Static("", id="worst", classes="panel")
            with Vertical(id="results-right"):
                yield Static("", id="curve-title")
                yield PlotextPlot(id="curve")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.action_fit(quiet=True)

    def on_screen_resume(self) -> None:
        if self.health is None or self.app.station.results_stale():  # type: ignore[attr-defined]
            self.action_fit(quiet=True)

    def action_fit(self, quiet: bool = False) -> None:
        if not self.app.station.has_measurements():  # type: ignore[attr-defined]
            if not quiet:
                self.notify("No measurements yet: run the plan first (3, r).", severity="warning")
            return
        self.query_one("#summary", Static).update(
            "Fitting the model to the run… (the UI stays live)"
        )
        self._fit()

    @work(thread=True, exclusive=True, group="fit")
    def _fit(self) -> None:
        try:
            h = self.app.station.results()  # type: ignore[attr-defined]
        except Exception as exc:
            self.app.call_from_thread(
                self.query_one("#summary", Static).update, f"[red]Fit failed: {exc}[/]"
            )
            return
        self.app.call_from_thread(self.set_health, h)

    def set_health(self, h: Health) -> None:
        self.health = h

    def watch_health(self, h: Health | None) -> None:
        if h is None:
            return
        colour = {HealthVerdict.HEALTHY: "green", HealthVerdict.DEGRADED: "yellow"}
        head, *rest = h.verdict_lines
        word, _, why = head.partition(": ")
        lines = [
            f"[b {colour.get(h.verdict, 'red')}]{escape(word)}[/]: {escape(why)}",
            *(escape(x) for x in rest),
            "",
            f"run {h.run_id} · {h.robot} · {h.n_poses} poses · fit residual "
            f"{h.rms_pos_mm:.3f} mm rms",
            "[b]Workspace TCP error[/b] (model, whole range): "
            f"mean {h.mean_mm:.3f} mm, std {h.std_mm:.3f} mm, max {h.max_mm:.3f} mm",
            f"  {spark(h.hist_counts, 24)}",
            f"  {h.hist_edges_mm[0]:<.2f}{'':>14}{h.hist_edges_mm[-1]:>.2f} mm",
        ]
        self.query_one("#summary", Static).update("\n".join(lines))
        worst = ["[b]Worst regions[/b] (mean error there)"] + [
            f" {r.err_mm:6.3f} mm {r.where}" for r in h.worst[:5]
        ]
        if h.pngs:
            worst.append(f"[dim]plots: {h.pngs[0].rsplit('/', 2)[-2]}/*.png[/]")
        self.query_one("#worst", Static).update("\n".join(worst))
        self._plot()

    def action_baseline(self) -> None:
        """``b``: this run becomes the robot's baseline (it must be fitted and archived)."""
        if self.health is None:
            self.notify("No results yet: fit the run first (f).", severity="warning")
            return
        self._set_baseline()

    @work(thread=True, exclusive=True, group="baseline")
    def _set_baseline(self) -> None:
        try:
            line = self.app.station.set_baseline()  # type: ignore[attr-defined]
        except Exception as exc:  # noqa: BLE001 - shown to the technician
            self.app.call_from_thread(self.notify, f"Baseline: {exc}", severity="error")
            return
        self.app.call_from_thread(self.notify, line)

    def action_joint(self, step: int) -> None:
        h = self.health
        if h is None:
            return
        joints = sorted({c.joint for c in h.curves}, key=lambda s: int(s[1:]))
        self.joint = (self.joint + step) % max(1, len(joints))

    def action_motion(self) -> None:
        self.motion = (self.motion + 1) % 6

    def watch_joint(self) -> None:
        self._plot()

    def watch_motion(self) -> None:
        self._plot()

    def _plot(self) -> None:
        h = self.health
        if h is None:
            return
        joints = sorted({c.joint for c in h.curves}, key=lambda s: int(s[1:]))
        if not joints:
            return
        jn = joints[self.joint % len(joints)]
        mo = MOTIONS[self.motion]
        curve = next((c for c in h.curves if c.joint == jn and c.motion == mo), None)
        widget = self.query_one("#curve", PlotextPlot)
        plt = widget.plt
        plt.clear_data()
        plt.clear_figure()
        title = self.query_one("#curve-title", Static)
        if curve is None:
            title.update(f"[b]{jn} {mo}[/b]: not in the model (zero)   [dim]j joint · m motion[/]")
            widget.refresh()
            return
        x = curve.q_deg.tolist()
        plt.plot(x, (curve.value + curve.band).tolist(), color="gray", marker="dot")
        plt.plot(x, (curve.value - curve.band).tolist(), color="gray", marker="dot")
        plt.plot(x, curve.value.tolist(), color="cyan", marker="braille")
        plt.yticks(*_ticks(curve.value - curve.band, curve.value + curve.band))
        title.update(
            f"[b]{jn} {curve.words}[/b] ({curve.unit}), dots: 95 % band   [dim]j joint · m motion[/]"
        )
        plt.xlabel(f"{jn} angle (deg)")
        widget.refresh()
