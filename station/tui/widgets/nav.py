"""The top line of every screen: where you are and how to get to the other screens."""

from __future__ import annotations

from textual.widgets import Static

SCREENS: tuple[tuple[str, str], ...] = (
    ("station", "Station"),
    ("plan", "Plan"),
    ("run", "Run"),
    ("results", "Results"),
    ("diagnose", "Diagnose"),
    ("history", "History"),
)


class NavBar(Static):
    """``quickhealth  1 Station  2 Plan …`` with the current screen highlighted."""

    def __init__(self, current: str) -> None:
        parts = ["[b]quickhealth[/b] "]
        for i, (mode, label) in enumerate(SCREENS, start=1):
            if mode == current:
                parts.append(f"[reverse b] {i} {label} [/]")
            else:
                parts.append(f" [b $accent]{i}[/] {label} ")
        parts.append("  [b $accent]q[/] quit")
        super().__init__("".join(parts), classes="nav")
