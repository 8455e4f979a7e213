"""``?``: what this application's screens are for and their keys, in the order of an assessment."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Static

#: Each screen: its key, name, what it answers, and its own keys.  The screens' BINDINGS are
#: the keys themselves; a test checks that every key named here is bound on its screen.
SCREENS_HELP: tuple[tuple[str, str, str, tuple[tuple[str, str], ...]], ...] = (
    (
        "1",
        "Station",
        "Is the station ready to measure? The devices, the cell, the accuracy spec, the "
        "archive, and the pre-flight go / no-go.",
        (("c", "connect (or reconnect) every device"), ("f", "run the pre-flight checks")),
    ),
    (
        "2",
        "Plan",
        "Which poses will the arm visit? The plan's poses, how it covers each joint's range, "
        "and a dry run on the simulated arm.",
        (
            ("d", "dry run: drive every leg on the simulator, nothing moves"),
            ("l", "reload the plan"),
        ),
    ),
    (
        "3",
        "Run",
        "Measure: the arm moves through the plan while the camera measures the target.",
        (
            ("r", "start (or continue) the run, after the pre-flight and your yes"),
            ("p", "pause after this pose / resume"),
            ("a", "abort: the robot stops first"),
            ("c", "reconnect after a fault, then r continues"),
            ("k", "quick check against the baseline: a few poses, 'unchanged' or 'changed'"),
        ),
    ),
    (
        "4",
        "Results",
        "Is the robot accurate enough, and has it changed? The verdict against the spec and "
        "the baseline, what to do, the TCP error over the workspace, each joint's curves.",
        (
            ("f", "fit the run (done by itself after a run)"),
            ("b", "make this run the robot's baseline"),
            ("j / J", "next / previous joint"),
            ("m", "next error motion"),
        ),
    ),
    (
        "5",
        "Diagnose",
        "Why? Measured against the model pose by pose, and which physical effect the model "
        "misses; add one and see the held-out error fall.",
        (
            ("d", "run the diagnosis"),
            ("s", "sort the poses"),
            ("a", "add the selected effect and refit"),
        ),
    ),
    (
        "6",
        "History",
        "Is it getting worse? Every run and quick check of this robot with its verdict, the "
        "latest run's verdict and the trend.",
        (("b", "make the selected run the baseline"), ("l", "reload from the archive")),
    ),
)

FIRST_TIME = (
    "First time on a robot: 1 (pre-flight), 3 then r (the full run), 4 (the verdict; the "
    "first run becomes the baseline). Next time: 3 then k (the quick check), or a full run "
    "and 4. Every verdict here is the one `quickhealth report` and `quickhealth trend` give."
)


def help_text() -> str:
    """The help in Rich markup."""
    out = ["[b]quickhealth at the station[/b]: one screen per step of an assessment.", ""]
    for key, name, what, keys in SCREENS_HELP:
        out.append(f"[b $accent]{key}[/] [b]{name}[/b]: {what}")
        out += [f"      [b]{k}[/b]  {v}" for k, v in keys]
    out += [
        "",
        FIRST_TIME,
        "",
        "[b]?[/b] closes this help · [b]q[/b] quits (a run is stopped first)",
    ]
    return "\n".join(out)


class HelpScreen(ModalScreen[None]):
    """The application's own help: its screens and keys (``?`` or Escape closes it)."""

    BINDINGS = [
        Binding("question_mark", "dismiss", "Close"),
        Binding("escape", "dismiss", "Close", show=False),
    ]

    def compose(self) -> ComposeResult:
        with VerticalScroll(id="help-body"):
            yield Static(help_text(), id="help-text")
