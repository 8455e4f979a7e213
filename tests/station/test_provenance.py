"""quickhealth --version and the provenance every result file carries."""

from __future__ import annotations

import tomllib
from importlib import metadata
from pathlib import Path

from quickhealth.station.cli import main
from quickhealth.station.provenance import provenance, software_version

ROOT = Path(__file__).resolve().parents[2]


def _project_version() -> str:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def test_version_flag_prints_the_package_version(capsys) -> None:
    assert main(["--version"]) == 0  # main() returns argparse's exit status, never raises
    assert capsys.readouterr().out == f"quickhealth {_project_version()}\n"
    assert software_version() == _project_version() == metadata.version("quickhealth")


def test_provenance_names_the_libraries_that_run() -> None:
    import cv2
    import numpy
    import pinocchio
    import scipy

    p = provenance()
    assert p["software"] == f"quickhealth {_project_version()}"
    assert p["numpy"] == numpy.__version__ == metadata.version("numpy")
    assert p["scipy"] == scipy.__version__ == metadata.version("scipy")
    assert p["pinocchio"] == pinocchio.__version__ == metadata.version("pin")
    assert p["opencv"] == metadata.version("opencv-contrib-python-headless")
    assert p["opencv"].startswith(cv2.__version__ + ".")  # the wheel's build number follows
    assert p["python"].count(".") == 2 and p["platform"].startswith("linux-")
    assert all(isinstance(v, str) and v and v != "not installed" for v in p.values())
