"""The question asked before the arm moves: a modal that dismisses with the answer."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Grid
from textual.screen import ModalScreen
from textual.widgets import Button, Label


class ConfirmScreen(ModalScreen[bool]):
    """Yes / no before motion: ``y`` or Enter moves, ``n`` or Escape does not."""

    BINDINGS = [
        Binding("y", "answer(True)", "Yes, move"),
        Binding("n,escape", "answer(False)", "No"),
    ]

    def __init__(self, question: str = "The arm will move. Is the cell clear?") -> None:
        super().__init__()
        self.question = question

    def compose(self) -> ComposeResult:
        with Grid(id="confirm-dialog"):
            yield Label(self.question, id="confirm-question")
            yield Button("Move (y)", variant="warning", id="yes")
            yield Button("Cancel (n)", variant="primary", id="no")

    def on_mount(self) -> None:
        self.query_one("#no", Button).focus()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.dismiss(event.button.id == "yes")

    def action_answer(self, yes: bool) -> None:
        self.dismiss(yes)
