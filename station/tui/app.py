"""The technician's terminal application (``quickhealth tui``).

Six screens, one per step of an assessment, each a *mode* so it keeps its state while the
technician moves between them with the number keys::

    1 Station   connections, cell and plan, pre-flight go / no-go
    2 Plan      plan summary, joint coverage, dry run on the simulator
    3 Run       progress, current pose, last measurement, pause / resume / abort
    4 Results   workspace error, verdict, per-joint curves, worst regions
    5 Diagnose  measured vs model, candidate effects, add one and refit
    6 History   this robot's runs and quick checks over time, with their verdicts
    ?           what the screens are for and their keys

The App talks only to a :class:`~quickhealth.station.tui.facade.Facade`, given to it in
``__init__``.  Everything slow (robot motion, fits, diagnosis) runs in thread workers on the
screens, which update the UI with ``call_from_thread``: the UI never blocks.
"""

from __future__ import annotations

from textual.app import App
from textual.binding import Binding

from .facade import Facade
from .screens.confirm import ConfirmScreen
from .screens.diagnose import DiagnoseScreen
from .screens.help import HelpScreen
from .screens.history import HistoryScreen
from .screens.plan import PlanScreen
from .screens.results import ResultsScreen
from .screens.run import RunScreen
from .screens.station import StationScreen


class QuickhealthApp(App[int]):
    """quickhealth at the station: keyboard first, fits an 80×24 terminal."""

    CSS_PATH = "quickhealth.tcss"
    TITLE = "quickhealth"
    MODES = {
        "station": StationScreen,
        "plan": PlanScreen,
        "run": RunScreen,
        "results": ResultsScreen,
        "diagnose": DiagnoseScreen,
        "history": HistoryScreen,
    }
    DEFAULT_MODE = "station"
    ENABLE_COMMAND_PALETTE = False
    SCREENS = {"confirm": ConfirmScreen}
    BINDINGS = [
        Binding("1", "switch_mode('station')", "Station", show=False),
        Binding("2", "switch_mode('plan')", "Plan", show=False),
        Binding("3", "switch_mode('run')", "Run", show=False),
        Binding("4", "switch_mode('results')", "Results", show=False),
        Binding("5", "switch_mode('diagnose')", "Diagnose", show=False),
        Binding("6", "switch_mode('history')", "History", show=False),
        Binding("q", "quit", "Quit", priority=True, show=False),
        Binding("question_mark", "toggle_help", "Help"),
    ]

    def __init__(self, station: Facade) -> None:
        super().__init__()
        self.station = station
        self.sub_title = station.title()

    def on_mount(self) -> None:
        """Follow the terminal's light or dark default; keep it readable over SSH."""
        self.theme = "textual-dark"

    def action_toggle_help(self) -> None:
        """``?``: what this application's screens are for and their keys (``?`` closes it)."""
        if isinstance(self.screen, HelpScreen):
            self.screen.dismiss()
        else:
            self.push_screen(HelpScreen())

    def action_quit(self) -> None:  # type: ignore[override]
        """Quit; a running plan is stopped first so the arm never moves unattended."""
        self.station.shutdown()
        self.exit(0)
