"""The wheel is the whole tool: built by ``python -m build``, installed (not editable) into a new
virtual environment, it plans, simulates, fits and reports from outside the source tree.

The new environment holds only the wheel and what the wheel's own metadata requires, at the
locked versions (``uv`` links them from its cache: no download after the first ``make test``).
Nothing of the source tree is importable there, so a file missing from the wheel, a package
missing from pyproject.toml or a dependency missing from its metadata fails here.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tomllib
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("identify", "vision", "station")
VERSION = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
_IGNORE = shutil.ignore_patterns(
    ".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", "*.pyc", ".*_cache",
    ".hypothesis", "out", "demo-output",
)  # fmt: skip


def _run(cmd: list[str], *, cwd: Path, env: dict[str, str], timeout: float = 240) -> str:
    out = subprocess.run(
        cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False
    )
    assert out.returncode == 0, f"{' '.join(map(str, cmd))} exited {out.returncode}:\n" + (
        out.stdout[-3000:] + out.stderr[-3000:]
    )
    return out.stdout + out.stderr


def _clean_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # else distutils warns that it cannot byte-compile
    env.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MPLBACKEND="Agg", **extra)
    return env


def _source_files() -> set[str]:
    """Every file the three folders hold, as its path inside the wheel."""
    out = set()
    for folder in FOLDERS:
        for f in (ROOT / folder).rglob("*"):
            if f.is_file() and "__pycache__" not in f.parts and f.suffix != ".pyc":
                out.add(f"quickhealth/{f.relative_to(ROOT).as_posix()}")
    return out


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path, str]:
    """(wheel, sdist, build log): ``python -m build`` on a copy of the tree (sdist, then the
    wheel from the sdist, so the sdist must be complete too), with the locked setuptools."""
    tmp = tmp_path_factory.mktemp("build")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=_IGNORE)
    cmd = [sys.executable, "-m", "build", "--no-isolation", "--outdir", str(tmp / "dist"), "."]
    log = _run(cmd, cwd=src, env=_clean_env())
    (wheel,) = (tmp / "dist").glob("quickhealth-*.whl")
    (sdist,) = (tmp / "dist").glob("quickhealth-*.tar.gz")
    return wheel, sdist, log


@pytest.fixture(scope="module")
def venv(built, tmp_path_factory) -> Path:
    """A new virtual environment with the wheel and its requirements at the locked versions."""
    uv = shutil.which("uv", path=str(Path(sys.executable).parent))
    if uv is None:
        pytest.skip("uv is not in this environment (make test installs it from requirements.lock)")
    v = tmp_path_factory.mktemp("venv") / "v"
    env = _clean_env()
    _run([uv, "venv", "--quiet", "--python", sys.executable, str(v)], cwd=v.parent, env=env)
    lock = str(ROOT / "requirements.lock")
    py = str(v / "bin" / "python")
    _run([uv, "pip", "install", "--quiet", "--python", py, str(built[0]), "-c", lock],
         cwd=v.parent, env=env)  # fmt: skip
    return v


def test_build_is_clean_and_the_wheel_and_sdist_hold_every_file(built) -> None:
    wheel, sdist, log = built
    warnings = sorted(set(re.findall(r"\b\w+Warning\b.*", log)))
    assert not warnings, "setuptools warned while building:\n" + "\n".join(warnings)
    assert wheel.name == f"quickhealth-{VERSION}-py3-none-any.whl"
    names = set(zipfile.ZipFile(wheel).namelist())
    want = _source_files()
    assert {
        "quickhealth/station/data/reference_cell.toml",
        "quickhealth/station/tui/quickhealth.tcss",
        "quickhealth/vision/data/reference_target.json",
        "quickhealth/vision/data/reference_rig.json",
    } <= want
    missing = sorted(want - names)
    assert not missing, f"not in the wheel: {missing}"
    extra = sorted(n for n in names - want if not n.startswith(f"quickhealth-{VERSION}.dist-info/"))
    assert not extra, f"in the wheel but not in the source: {extra}"
    with tarfile.open(sdist) as tf:
        in_sdist = {n.split("/", 1)[1] for n in tf.getnames() if "/" in n}
    missing = sorted(f for f in want if f.removeprefix("quickhealth/") not in in_sdist)
    assert not missing, f"not in the sdist: {missing}"
    meta = zipfile.ZipFile(wheel).read(f"quickhealth-{VERSION}.dist-info/METADATA").decode()
    assert (
        "Requires-Dist: pin>=" in meta and "Requires-Dist: opencv-contrib-python-headless" in meta
    )


def test_installed_wheel_plans_simulates_fits_and_reports(venv, tmp_path) -> None:
    bindir = venv / "bin"
    env = _clean_env(PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}")
    qh = str(bindir / "quickhealth")
    work = tmp_path / "outside"  # not the source tree: nothing of it is importable here
    work.mkdir()

    # quickhealth and its data come from the wheel, not editable, never from the source tree
    probe = r"""
import importlib, json, pkgutil, sys
from importlib import metadata, resources
mods = []
for top in ("identify", "vision", "station"):
    p = importlib.import_module("quickhealth." + top)
    mods += [p] + [importlib.import_module(m.name)
                   for m in pkgutil.walk_packages(p.__path__, p.__name__ + ".")]
data = [resources.files("quickhealth.station.tui").joinpath("quickhealth.tcss"),
        resources.files("quickhealth.station.data").joinpath("reference_cell.toml"),
        resources.files("quickhealth.vision.data").joinpath("reference_target.json")]
dist = metadata.distribution("quickhealth")
print(json.dumps({"files": [m.__file__ for m in mods], "data": [len(d.read_bytes()) for d in data],
                  "direct_url": dist.read_text("direct_url.json"), "prefix": sys.prefix}))
"""
    doc = json.loads(_run([str(bindir / "python"), "-c", probe], cwd=work, env=env))
    site = str(venv / "lib")
    assert len(doc["files"]) > 80 and all(f.startswith(site) for f in doc["files"]), [
        f for f in doc["files"] if not f.startswith(site)
    ][:5]
    assert not any(f.startswith(str(ROOT)) for f in doc["files"])
    assert min(doc["data"]) > 100
    assert '"editable"' not in (doc["direct_url"] or "")

    assert _run([qh, "--version"], cwd=work, env=env).strip() == f"quickhealth {VERSION}"

    _run([qh, "plan", "--cell", "reference", "--n", "40", "--out", "plan"], cwd=work, env=env)
    plan = json.loads((work / "plan" / "plan.json").read_text())
    assert plan["n_generated"] == 40 and 5 <= len(plan["poses"]) <= 40
    script = (work / "plan" / "loop.script").read_text()
    assert len(re.findall(r"\bmove[jl]\(", script)) >= len(plan["poses"])
    assert (work / "plan" / "fig6_joints.png").stat().st_size > 10_000

    twin = ["twin", "--effects", "backlash:j2=0.025", "--n", "60", "--heldout", "100"]
    _run([qh, *twin, "--seed", "4", "--out", "t/measurements.csv"], cwd=work, env=env)
    assert len((work / "t" / "measurements.csv").read_text().splitlines()) > 60

    out = _run([qh, "identify", "fit", "t/measurements.csv", "--robot", "ur5", "--out", "t"],
               cwd=work, env=env)  # fmt: skip
    assert "wrote t/model.json" in out
    model = json.loads((work / "t" / "model.json").read_text())
    report = json.loads((work / "t" / "report.json").read_text())
    assert model["stats"]["converged"] and model["stats"]["n_poses"] == 60
    assert 0 < report["rms_pos_mm"] < 0.5
    for doc in (model, report):  # the versions that ran in the new environment
        prov = doc["provenance"]
        assert prov["software"] == f"quickhealth {VERSION}"
        assert {"numpy", "scipy", "opencv", "pinocchio"} <= set(prov)
        assert all(prov[k][0].isdigit() for k in ("numpy", "scipy", "opencv", "pinocchio"))

    _run([qh, "report", "t"], cwd=work, env=env)
    html = (work / "t" / "report.html").read_text()
    assert html.startswith("<!DOCTYPE html>")
    assert "quickhealth report: ur5" in html and html.count("data:image/png;base64,") >= 2


def test_new_environment_holds_only_locked_versions(venv) -> None:
    from importlib import metadata

    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import lockfile
    finally:
        sys.path.remove(str(ROOT / "tools"))
    pins = lockfile.applicable(lockfile.read_lock())
    (site,) = (venv / "lib").glob("python3*/site-packages")
    got = {
        lockfile.normalize(d.metadata["Name"]): d.version
        for d in metadata.distributions(path=[str(site)])
    }
    assert got.pop("quickhealth") == VERSION
    assert {"numpy", "scipy", "opencv-contrib-python-headless", "pin", "textual"} <= set(got)
    assert "pytest" not in got and "ruff" not in got  # runtime requirements only
    wrong = {n: v for n, v in got.items() if n not in pins or pins[n].version != v}
    assert not wrong, f"not the locked versions: {wrong}"
