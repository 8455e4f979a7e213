"""Screen 2, Plan: what will be measured, what was dropped and why, joint coverage, dry run."""

from __future__ import annotations

from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import Screen
from textual.widgets import Footer, Static

from ..views import DryRun, PlanView
from ..widgets.nav import NavBar
from ..widgets.textplot import bar, fmt_duration, spark


class PlanScreen(Screen[None]):
    """The frozen plan: ``d`` runs it on the simulator without capture (a dry run)."""

    BINDINGS = [
        Binding("d", "dry_run", "Dry run"),
        Binding("l", "reload", "Reload plan"),
    ]

    def compose(self) -> ComposeResult:
        yield NavBar("plan")
        with Horizontal(id="plan-body"):
            with Vertical(id="plan-left"):
                yield Static("", id="plan-summary", classes="panel")
                yield Static(
                    "Dry run: press [b]d[/b] to try the loop on the simulator.",
                    id="dry-run",
                    classes="panel",
                )
            yield Static("", id="coverage", classes="panel")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.action_reload()

    def on_resize(self) -> None:
        if getattr(self, "_plan", None) is not None:
            self.show_plan(self._plan)

    def action_reload(self) -> None:
        self._load()

    @work(thread=True, exclusive=True, group="plan")
    def _load(self) -> None:
        try:
            pv = self.app.station.plan_view()  # type: ignore[attr-defined]
        except Exception as exc:  # shown, not raised: the technician picks another plan
            self.app.call_from_thread(
                self.query_one("#plan-summary", Static).update, f"[red]{exc}[/]"
            )
            return
        self.app.call_from_thread(self.show_plan, pv)

    def show_plan(self, pv: PlanView) -> None:
        self._plan = pv
        lines = [
            f"[b]Plan[/b] {pv.path}",
            f"cell {pv.cell} · hash {pv.plan_hash[:12]}",
            "",
            f"generated  {pv.n_generated:4d}",
            f"[green]kept[/]       {pv.n_kept:4d}",
            f"  legs {pv.n_linear} linear, {pv.n_joint} joint",
            f"dropped    {pv.n_generated - pv.n_kept:4d}",
        ]
        for reason, n in sorted(pv.dropped.items(), key=lambda kv: -kv[1]):
            lines.append(f"  {n:4d}  {reason}")
        if pv.evenness is not None:
            lines.append(f"evenness   {pv.evenness:.2f}")
        self.query_one("#plan-summary", Static).update("\n".join(lines))
        width = max(10, self.query_one("#coverage").size.width - 18)
        cov = ["[b]Joint coverage[/b] (kept poses over each joint's usable range)", ""]
        for jc in pv.coverage:
            cov.append(f"{jc.joint:>3} {spark(jc.counts, width)} {jc.covered:4.0%}")
            cov.append(f"    {jc.lo_deg:<+7.0f}{'':>{max(0, width - 14)}}{jc.hi_deg:>+7.0f}°")
        self.query_one("#coverage", Static).update("\n".join(cov))

    def action_dry_run(self) -> None:
        self.query_one("#dry-run", Static).update("Dry run on the simulator…")
        self._dry_run()

    @work(thread=True, exclusive=True, group="plan")
    def _dry_run(self) -> None:
        try:
            dr = self.app.station.dry_run()  # type: ignore[attr-defined]
        except Exception as exc:
            self.app.call_from_thread(
                self.query_one("#dry-run", Static).update, f"[red]Dry run failed: {exc}[/]"
            )
            return
        self.app.call_from_thread(self.show_dry_run, dr)

    def show_dry_run(self, dr: DryRun) -> None:
        head = "[b green]Dry run OK[/]" if dr.ok else "[b red]Dry run found problems[/]"
        lines = [head, f"{dr.n_poses} poses, loop time {fmt_duration(dr.duration_s)}"]
        lines += [f"[red]•[/] {p}" for p in dr.problems[:6]]
        if dr.ok:
            lines.append(bar(1.0, 20))
        self.query_one("#dry-run", Static).update("\n".join(lines))
