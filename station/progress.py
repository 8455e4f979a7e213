"""Progress of long commands on stderr: a bar on a terminal, one line per stage in logs.

``identify fit``, ``diagnose`` and ``identify compare`` run for seconds to a minute on
thousands of poses.  A technician at a terminal sees a live bar (rich, drawn only once the
work has taken longer than ``delay`` seconds, and cleared when it ends, so short commands
print nothing extra); a nightly job's log gets one line per stage, which is what a log can
hold; ``--quiet`` silences both.  Results always go to stdout: this writes to stderr only.

SYNOPSIS::

    with Progress(quiet=args.quiet) as say:
        say("searching orders")            # a stage
        say.advance(3, 120, "candidates")  # within a stage (bar on a terminal only)
"""

from __future__ import annotations

import sys
import time
from types import TracebackType
from typing import Any, TextIO

#: Seconds of work before a terminal shows the bar.
DELAY_S = 2.0


class Progress:
    """Stages and fractions of one command's work (see the module docstring)."""

    def __init__(
        self, *, quiet: bool = False, stream: TextIO | None = None, delay: float = DELAY_S
    ) -> None:
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self.delay = delay
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.monotonic()
        self.stage = ""
        self._bar: Any = None
        self._task: Any = None
        self._logged = ""

    # ---- stages
    def __call__(self, text: str) -> None:
        """A new stage (or a line of the work's own account, e.g. an accepted order move)."""
        if self.quiet:
            return
        self.stage = text
        if self.tty:
            if self._bar is not None:  # a new stage: no fraction known yet (a spinner)
                self._bar.reset(self._task, total=None, description=text)
            self._draw(None, None)
        else:
            self.stream.write(f"  {text}\n")
            self.stream.flush()
            self._logged = text

    def advance(self, done: int, total: int, text: str | None = None) -> None:
        """``done`` of ``total`` items of the current stage (``text`` names the items)."""
        if self.quiet:
            return
        if text is not None and text != self.stage:
            self.stage = text
            if not self.tty and text != self._logged:  # a log gets the stage once
                self.stream.write(f"  {text} ({total})\n")
                self.stream.flush()
                self._logged = text
        if self.tty:
            self._draw(done, total)

    # ---- the terminal's bar
    def _draw(self, done: int | None, total: int | None) -> None:
        if self._bar is None:
            if time.monotonic() - self.t0 < self.delay:
                return
            # rich only once a bar is due (0.2 s to import: short commands never pay it)
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                SpinnerColumn,
                TaskProgressColumn,
                TextColumn,
                TimeElapsedColumn,
            )
            from rich.progress import (
                Progress as RichProgress,
            )

            self._bar = RichProgress(
                SpinnerColumn(),
                TextColumn("{task.description}"),
                BarColumn(),
                TaskProgressColumn(),
                TimeElapsedColumn(),
                console=Console(file=self.stream),
                transient=True,
            )
            self._bar.start()
            self._task = self._bar.add_task(self.stage, total=None)
        self._bar.update(self._task, description=self.stage, completed=done, total=total)

    def close(self) -> None:
        """Clear the bar (the terminal keeps only the command's own output)."""
        if self._bar is not None:
            self._bar.stop()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
