"""``quickhealth tui``: the command line contract and quitting with ``q``."""

from __future__ import annotations

from pathlib import Path

from quickhealth.identify.twin import make_twin, random_joints
from quickhealth.station.cli import main
from quickhealth.station.formats import write_measurements
from quickhealth.station.tui.app import QuickhealthApp
from quickhealth.station.tui.facade import Facade
from quickhealth.station.tui.screens.help import SCREENS_HELP, HelpScreen


def test_tui_needs_a_station(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["tui"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--sim" in err and "Traceback" not in err


def test_tui_is_listed_in_the_help(capsys) -> None:  # type: ignore[no-untyped-def]
    try:
        main(["tui", "--help"])
    except SystemExit as exc:
        assert exc.code == 0
    out = capsys.readouterr().out
    assert "--sim" in out and "q quits" in out


async def test_q_quits_from_any_screen_and_help_lists_keys(tmp_path: Path) -> None:
    twin = make_twin(seed=3)
    q = random_joints(twin.robot, 12, seed=4, T_instr_base=twin.truth.T_instr_base)
    (tmp_path / "r").mkdir()
    write_measurements(tmp_path / "r" / "measurements.csv", twin.measure(q, seed=5))
    station = Facade.from_data(tmp_path / "r" / "measurements.csv", archive_root=tmp_path / "a")
    app = QuickhealthApp(station)
    async with app.run_test(size=(80, 24)) as pilot:
        await pilot.press("3")
        await pilot.pause()
        assert app.current_mode == "run"
        assert "no station attached" in str(app.screen.query_one("#run-state").render())
        await pilot.press("question_mark")
        await pilot.pause()
        # the application's own help: its six screens and what they are for, not textual's keys
        assert isinstance(app.screen, HelpScreen)
        help_text = str(app.screen.query_one("#help-text").render())
        for name in ("Station", "Plan", "Run", "Results", "Diagnose", "History", "baseline"):
            assert name in help_text, name
        await pilot.press("question_mark")  # closes it
        await pilot.pause()
        assert not isinstance(app.screen, HelpScreen) and app.current_mode == "run"
        await pilot.press("2")
        await pilot.pause()
        await pilot.press("q")
        await pilot.pause()
    assert app.return_value == 0


def test_help_names_only_keys_the_screens_bind() -> None:
    """Every key the help names for a screen is bound on that screen (help never lies)."""
    for _key, name, _what, keys in SCREENS_HELP:
        screen = QuickhealthApp.MODES[name.lower()]
        bound = {b.key for b in screen.BINDINGS}  # type: ignore[attr-defined]
        for k, _ in keys:
            for one in k.split(" / "):
                assert one in bound, (name, one)
