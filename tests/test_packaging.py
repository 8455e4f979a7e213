"""The environment is exactly requirements.lock; pyproject.toml lists every package folder."""

from __future__ import annotations

import fnmatch
import importlib.util
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = {"identify": "quickhealth.identify", "vision": "quickhealth.vision",
           "station": "quickhealth.station"}  # fmt: skip


def _lockfile():
    spec = importlib.util.spec_from_file_location("qh_lockfile", ROOT / "tools" / "lockfile.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def _setuptools_config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _package_folders() -> dict[str, Path]:
    """Every folder under identify/, vision/, station/ holding files, by its package name."""
    out = {}
    for folder, pkg in FOLDERS.items():
        for d in [ROOT / folder, *sorted((ROOT / folder).rglob("*"))]:
            if d.is_dir() and d.name != "__pycache__" and any(f.is_file() for f in d.iterdir()):
                rel = d.relative_to(ROOT / folder).parts
                out[".".join((pkg, *rel))] = d
    return out


def test_installed_distributions_are_exactly_the_lock() -> None:
    lf = _lockfile()
    pins = lf.applicable(lf.read_lock())
    assert {"numpy", "scipy", "opencv-contrib-python-headless", "pin", "textual", "uv"} <= set(pins)
    assert all(p.hashes for p in pins.values()), "every pin carries sha256 hashes"
    diff = lf.differences()
    assert diff == [], "\n".join(diff)


def test_lock_reader_sees_markers_hashes_and_a_bootstrap_requirement() -> None:
    lf = _lockfile()
    pins = lf.read_lock()
    assert len(pins) > 80
    colorama = next(p for p in pins if p.name == "colorama")  # only on Windows
    assert colorama.marker is not None and "win32" in colorama.marker
    assert "colorama" not in lf.applicable(pins) or sys.platform == "win32"
    uv = lf.bootstrap(["uv"])
    assert uv.startswith("uv==") and uv.count("--hash=sha256:") >= 2
    assert "# via" not in uv


def test_every_package_folder_is_listed_in_pyproject() -> None:
    listed = set(_setuptools_config()["packages"])
    folders = _package_folders()
    missing = sorted(set(folders) - listed)
    assert not missing, f"add {missing} to [tool.setuptools] packages in pyproject.toml"
    gone = sorted(listed - set(folders))
    assert not gone, f"{gone} listed in pyproject.toml but no such folder"


def test_every_data_file_is_package_data() -> None:
    data = _setuptools_config()["package-data"]
    left = []
    for pkg, d in _package_folders().items():
        for f in d.iterdir():
            if f.is_file() and f.suffix not in (".py", ".pyc"):
                if not any(fnmatch.fnmatch(f.name, pat) for pat in data.get(pkg, [])):
                    left.append(str(f.relative_to(ROOT)))
    assert not left, f"not in the wheel: {left} (add a pattern to [tool.setuptools.package-data])"
    assert _package_folders()["quickhealth.station.tui"].joinpath("quickhealth.tcss").is_file()
