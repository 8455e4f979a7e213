"""The three folders install as quickhealth.* and coexist with pre-commit's ``identify``."""

import importlib
import subprocess
import sys


def test_quickhealth_identify_coexists_with_precommit_identify() -> None:
    top = importlib.import_module("identify")
    ours = importlib.import_module("quickhealth.identify")
    from identify import identify as precommit_identify  # pre-commit's file-type sniffer

    assert top is not ours
    assert "site-packages" in (top.__file__ or "")
    assert "tags_from_filename" in dir(precommit_identify)
    assert ours.__doc__ and "assessment" in ours.__doc__
    assert precommit_identify.tags_from_filename("x.py") >= {"python"}


def test_console_script_help_exits_zero() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "quickhealth.station.cli", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0
    assert "quickhealth" in out.stdout


def test_unknown_command_is_usage_error() -> None:
    from quickhealth.station.cli import main

    try:
        rc = main(["no-such-command"])
    except SystemExit as exc:
        rc = exc.code
    assert rc == 2
