"""Progress on stderr: stage lines in a log, a bar only on a terminal and only after 2 s."""

from __future__ import annotations

import io

from quickhealth.station.progress import Progress


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_one_line_per_stage_and_quiet_gets_nothing():
    log = io.StringIO()
    with Progress(stream=log) as say:
        say("searching orders")
        for i in range(50):
            say.advance(i, 50, "testing candidate effects")
        say("writing")
    assert log.getvalue() == ("  searching orders\n  testing candidate effects (50)\n  writing\n")
    quiet = io.StringIO()
    with Progress(stream=quiet, quiet=True) as say:
        say("searching orders")
        say.advance(1, 2, "x")
    assert quiet.getvalue() == ""


def test_a_terminal_gets_a_bar_only_once_the_work_is_long():
    fast = _Tty()
    with Progress(stream=fast, delay=60.0) as say:
        say("searching orders")
        say.advance(1, 2, "testing")
    assert fast.getvalue() == ""  # a short command prints nothing extra
    slow = _Tty()
    with Progress(stream=slow, delay=0.0) as say:
        say("searching orders")
        say.advance(5, 10, "testing candidate effects")
    out = slow.getvalue()
    assert "testing candidate effects" in out and "50%" in out
